"""Explicit-scenario suites (envs/explicit.py): written, loaded, run like any suite."""

import hashlib
import tomllib

import numpy as np
import pytest

from overtakezoo import zoo
from overtakezoo.benchmark.run.runner import run_indices, run_suite
from overtakezoo.envs.config import ConfigError
from overtakezoo.envs.draws import space_for
from overtakezoo.envs.explicit import ExplicitDistribution, entries_of, suite_tables, to_toml
from overtakezoo.envs.suites import load_suite, parse_suite


def explicit_file(tmp_path, suite_name="table1", n=6, params=None, seed=0, name="listed"):
    suite = load_suite(suite_name)
    space = space_for(suite.distribution, params)
    unit = np.random.default_rng(seed).uniform(size=(n, space.size))
    doc = {
        "name": name,
        "version": 1,
        "count": n,
        "seed": 0,
        "scenario": space.base.to_dict(),
        "sim": suite_tables(suite),
        "scenarios": entries_of(space, space.values(unit)),
    }
    path = tmp_path / f"{name}.toml"
    path.write_bytes(to_toml("a test suite", doc))
    return path, space, unit, suite


@pytest.mark.parametrize(
    "suite_name, params",
    [
        ("table1", None),
        ("oncoming-4", None),
        ("dense", None),
        ("occluded", None),
        ("duel", None),
        ("oncoming-4", ["oncoming_count=0:4", "sensor_range=10:90", "oncoming_speed"]),
    ],
)
def test_listed_scenarios_load_as_built(tmp_path, suite_name, params):
    path, space, unit, _ = explicit_file(tmp_path, suite_name, params=params)
    suite = load_suite(path)
    assert isinstance(suite.distribution, ExplicitDistribution) and suite.count == 6
    assert suite.hash == hashlib.sha256(path.read_bytes()).hexdigest()
    want, got = space.build(unit), suite.scenarios()
    for key, a in want.to_arrays().items():
        assert np.array_equal(a, getattr(got, key)), key
    assert suite.scenarios(shard=(1, 2)).num == 3  # shards slice the list


def test_an_explicit_suite_runs_like_any(tmp_path):
    path, space, unit, base = explicit_file(tmp_path)
    suite = load_suite(path)
    d = zoo.load("rule-fsm", suite.config)
    res = run_suite(suite, d, progress=False)
    per = run_indices(load_suite("table1"), d, np.arange(0))  # (a drawn suite still runs)
    assert res.suite["hash"] == suite.hash and res.per_scenario_array("outcome").size == 6 and per["outcome"].size == 0
    # Each listed scenario behaves as the same scenario drawn in a batch of its own.
    from overtakezoo.benchmark.failures.search import evaluate

    ev = evaluate(base, d, space.build(unit))
    assert np.array_equal(ev.outcome, res.per_scenario_array("outcome"))


def test_a_face_refills_from_the_list(tmp_path):
    path, *_ = explicit_file(tmp_path)
    dist = load_suite(path).distribution
    rows = dist.sample(10, np.random.default_rng(0))  # (as a trainer's auto-reset source calls it)
    assert rows.num == 10 and set(np.round(rows.npc_s[:, 0], 6)) <= set(np.round(dist.sample(6, 0).npc_s[:, 0], 6))
    with pytest.raises(ValueError):
        dist.sample(7, 0)


def edit(path, old, new):
    """``old`` -> ``new`` once: in the first [[scenarios]] entry, or at the top for top-level keys."""
    text = path.read_text()
    head, sep, rest = text.partition("[[scenarios]]")
    if old in head.split("[scenario]")[0] or old == "[[scenarios]]\n":
        path.write_text(text.replace(old, new, 1))
    else:
        assert old in rest
        path.write_text(head + sep + rest.replace(old, new, 1))
    return path


@pytest.mark.parametrize(
    "old, new, needle",
    [
        ("count = 6", "count = 5", "count: 5 but 6 [[scenarios]] are listed"),
        ("lead_boost = 0.0\n", "", "scenarios[0].lead_boost: missing"),
        ("lead_boost = 0.0\n", "lead_boost = 0.0\nlead_bost = 1.0\n", "scenarios[0].lead_bost: unknown key"),
        ("oncoming_speed = [", "oncoming_speed = [1.0, ", "scenarios[0].oncoming_speed: expected a list of 1 numbers"),
        ("ego_speed = 4.166666666666667\n", "ego_speed = 5.0\n", "is outside the [scenario] table's range"),
        ("lead_gap = ", 'lead_gap = "x" #', "scenarios[0].lead_gap: expected a finite number"),
        ("lead_gap = ", "lead_gap = inf #", "scenarios[0].lead_gap: expected a finite number"),
        ("[[scenarios]]\n", "[[scenarios]]\noncoming_count = 99\n", "oncoming_count: expected an integer in [0, 64]"),
        ('name = "listed"', 'name = "listed"\nbase = "table1"', "scenarios: a suite with a base"),
        ('name = "listed"', 'name = "listed"\nsearch = 3', "search: expected a table"),
    ],
)
def test_bad_lists_are_one_error_naming_the_entry(tmp_path, old, new, needle):
    path, *_ = explicit_file(tmp_path)
    with pytest.raises(ConfigError) as exc:
        load_suite(edit(path, old, new))
    assert needle in str(exc.value) and str(path) in str(exc.value)


def test_no_scenarios_listed(tmp_path):
    data = load_suite("table1").path.read_bytes() + b"\n[search]\nnote = 'x'\n"
    with pytest.raises(ConfigError, match="scenarios: expected one or more"):
        parse_suite(data, tmp_path / "x.toml")


def test_toml_writer_reads_back():
    doc = {
        "a": 1.0000000000000002,
        "b": [1e-05, float("inf"), -0.0],
        "c": 'q"\\\n',
        "t": {"u": {"v": True}},
        "arr": [{"x": 1, "y": {"z": 2}}, {"x": 2}],
        "empty": [],
    }
    back = tomllib.loads(to_toml("h", doc).decode())
    assert back == doc
