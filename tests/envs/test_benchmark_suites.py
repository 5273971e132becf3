"""Suites: built-in files load, hashes are the file bytes, shards slice, bad files are UserErrors."""

import hashlib
import string

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import suite_file
from overtakezoo.envs.suites import (
    SUITES_DIR,
    SuiteError,
    load_suite,
    parse_shard,
    parse_suite,
    shard_bounds,
    suite_names,
)

EXPECTED = {
    "table1",
    "table1-train",
    "oncoming-2",
    "oncoming-4",
    "oncoming-8",
    "dense",
    "urban-50",
    "adversarial",
    "occluded",
}


def test_builtin_suites_load_with_file_hash():
    assert EXPECTED <= set(suite_names())
    for name in EXPECTED:
        s = load_suite(name)
        assert s.name == name and s.builtin
        assert s.hash == hashlib.sha256((SUITES_DIR / f"{name}.toml").read_bytes()).hexdigest()
    t1, train = load_suite("table1"), load_suite("table1-train")
    assert t1.count == 3000 and train.count == 1000 and t1.seed != train.seed
    assert t1.distribution == train.distribution
    assert load_suite("oncoming-4").distribution.oncoming_count == 4
    assert load_suite("dense").distribution.follower_count == 2
    assert load_suite("adversarial").distribution.lead_behaviour == "speedup"
    assert load_suite("occluded").distribution.sensor_range < t1.distribution.sensor_range
    urban = load_suite("urban-50").distribution
    assert urban.speed_limit == pytest.approx(50 / 3.6) and urban.lead_speed == pytest.approx((30 / 3.6, 12.5))


def test_load_by_path_and_shards(tmp_path):
    path = suite_file(tmp_path / "mine.toml", 10)
    s = load_suite(str(path))
    assert s.name == "mine" and s.count == 10 and not s.builtin
    full = s.scenarios()
    parts = [s.scenarios((i, 3)) for i in range(3)]
    assert [p.num for p in parts] == [3, 3, 4]
    np.testing.assert_array_equal(np.concatenate([p.npc_s for p in parts]), full.npc_s)
    assert shard_bounds(10, None) == (0, 10) and parse_shard("1/4") == (1, 4)
    for bad in ("4/4", "x", "-1/2", "1/0"):
        with pytest.raises(SuiteError):
            parse_shard(bad)
    with pytest.raises(SuiteError):
        shard_bounds(10, (0, 11))


@pytest.mark.parametrize(
    "text, needle",
    [
        ("name = ", "malformed TOML"),
        ('name = "x"\nversion = 1\ncount = 5\nseed = 1\nbogus = 2\n[scenario]\n', "bogus"),
        ('name = "x"\nversion = 1\ncount = 5\nseed = 1\n', "scenario: missing"),
        ('name = "x"\nversion = 1\ncount = 0\nseed = 1\n[scenario]\n', "count"),
        ('name = "X Y"\nversion = 1\ncount = 5\nseed = 1\n[scenario]\n', "name"),
        ('name = "x"\nversion = 1\ncount = 5\nseed = 1\n[scenario]\nlead_gapp = [1, 2]\n', "scenario.lead_gapp"),
        ('name = "x"\nversion = 1\ncount = 5\nseed = 1\n[scenario]\nlead_gap = [3, 2]\n', "scenario.lead_gap"),
        ('name = "x"\nversion = 1\ncount = 5\nseed = 1\n[scenario]\n[sim]\ndt = 5\n', "sim.dt"),
        ('name = "x"\nversion = 1\ncount = 5\nseed = 1\n[scenario]\n[sim]\nfoo = 5\n', "sim.foo"),
    ],
)
def test_bad_suite_files_name_the_problem(tmp_path, text, needle):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(SuiteError, match=needle.replace(".", r"\.")):
        load_suite(path)


def test_unknown_suite_name():
    with pytest.raises(SuiteError, match="unknown suite 'nope'"):
        load_suite("nope")


_GOOD = (SUITES_DIR / "table1.toml").read_text()
_lines = _GOOD.splitlines()


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.one_of(
        st.binary(max_size=200),
        st.text(alphabet=string.printable, max_size=200),
        # A real suite with one line replaced by junk or removed: mostly valid TOML with bad values.
        st.tuples(
            st.integers(0, len(_lines) - 1),
            st.sampled_from(
                [
                    "",
                    "count = -3",
                    "seed = 1.5",
                    "lead_gap = [1]",
                    "x = 1",
                    'goal = "far"',
                    "[sim]",
                    "[sim.planner]",
                    "decision_interval = 0",
                    "version = true",
                    'lead_behaviour = "wild"',
                    "oncoming_count = 99",
                    "sensor_range = -1",
                    "[scenario]",
                    "name = 3",
                ]
            ),
        ).map(lambda t: "\n".join(_lines[: t[0]] + [t[1]] + _lines[t[0] + 1 :])),
    )
)
def test_fuzz_suite_loader_raises_only_user_errors(data):
    raw = data if isinstance(data, bytes) else data.encode()
    try:
        parse_suite(raw, SUITES_DIR / "fuzz.toml")
    except SuiteError as exc:
        assert str(exc) and "\n" not in str(exc).strip()


# Issue 18: every setting has a physical range, kept once in its dataclass field (envs/config.py
# `bounded`), documented in docs/settings.md; every default and every shipped suite lies inside.
def _ranged_classes():
    from overtakezoo.envs.config import EnvConfig, NPCConfig, ObservationConfig, PlannerConfig, RewardConfig
    from overtakezoo.envs.scenarios import ScenarioDistribution

    return {
        "scenario": ScenarioDistribution,
        "sim": EnvConfig,
        "sim.planner": PlannerConfig,
        "sim.npc": NPCConfig,
        "sim.reward": RewardConfig,
        "sim.observation": ObservationConfig,
    }


def settings_rows():
    """One docs row per ranged setting: | table | key | low | high | unit |."""
    import dataclasses

    rows = []
    for table, cls in _ranged_classes().items():
        for f in dataclasses.fields(cls):
            if "lo" in f.metadata:
                m = f.metadata
                rows.append(f"| `[{table}]` | `{f.name}` | {m['lo']:g} | {m['hi']:g} | {m['unit']} |")
    return rows


def test_every_number_setting_has_a_range_holding_its_default_and_the_shipped_suites():
    import dataclasses
    import math

    for table, cls in _ranged_classes().items():
        for f in dataclasses.fields(cls):
            default = f.default
            if isinstance(default, bool) or not isinstance(default, (int, float, tuple)):
                continue
            assert "lo" in f.metadata, f"[{table}] {f.name} has no range"
            values = default if isinstance(default, tuple) else (default,)
            lo, hi = f.metadata["lo"], f.metadata["hi"]
            assert all(lo <= v <= hi or math.isinf(v) for v in values), (table, f.name, default)
    cls = _ranged_classes()
    cls["sim"]()  # the defaults validate
    for name in suite_names():  # and so does every shipped suite (load_suite validates)
        assert load_suite(name).name == name


def test_the_settings_doc_lists_every_range():
    doc = (SUITES_DIR.parents[1] / "docs" / "settings.md").read_text()
    missing = [row for row in settings_rows() if row not in doc]
    assert not missing, "docs/settings.md is out of date; rows to add:\n" + "\n".join(missing)
