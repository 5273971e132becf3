"""Runner and results files: Table I behaviour of the fixed baselines, determinism, shards, hooks."""

import json

import numpy as np
import pytest

from conftest import suite_file
from overtakezoo import zoo
from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.results.results import Results, merge
from overtakezoo.benchmark.run.runner import run_suite
from overtakezoo.envs import CRASH, SUCCESS, TIMEOUT
from overtakezoo.envs.suites import load_suite


def small_suite(tmp_path, count=60, name="small"):
    return load_suite(suite_file(tmp_path / f"{name}.toml", count))


def test_always_follow_on_table1_is_safe_and_never_succeeds():
    suite = load_suite("table1")
    r = run_suite(suite, zoo.load("always-follow", suite.config), progress=False)
    assert r.per["outcome"].shape == (3000,)
    assert r.summary["success_rate"]["value"] == 0.0
    assert r.summary["crash_rate"]["k"] == 0
    assert np.all(r.per["outcome"] == TIMEOUT)


def test_always_overtake_crashes_mostly_with_npc2():
    suite = load_suite("table1")
    r = run_suite(suite, zoo.load("always-overtake", suite.config), shard=(0, 10), progress=False)
    crashes = r.per["outcome"] == CRASH
    assert crashes.sum() > 10 and (r.per["outcome"] == SUCCESS).sum() > 10
    assert r.summary["crash_share_npc2"]["value"] > 0.5
    assert np.all(r.per["crash_lane"][crashes] >= 0)


def test_same_run_twice_is_byte_identical_apart_from_timing(tmp_path):
    suite = small_suite(tmp_path)
    runs = [run_suite(suite, zoo.load("always-overtake", suite.config), progress=False) for _ in range(2)]
    paths = [runs[i].save(tmp_path / f"r{i}.json") for i in range(2)]
    docs = [json.loads(p.read_text()) for p in paths]
    assert "wall_time_s" in docs[0]["timing"]
    for d in docs:
        d.pop("timing")
    assert docs[0] == docs[1]
    assert runs[0].without_timing() == runs[1].without_timing()
    loaded = Results.load(paths[0])
    assert loaded.to_json() == paths[0].read_text()


def test_shards_merge_into_the_single_run(tmp_path):
    suite = small_suite(tmp_path, count=50)
    decider = zoo.load("always-overtake", suite.config)
    full = run_suite(suite, decider, progress=False)
    parts = [run_suite(suite, decider, shard=(i, 3), chunk_size=7, progress=False) for i in (2, 0, 1)]
    merged = merge(parts)
    assert merged.without_timing() == full.without_timing()
    with pytest.raises(UserError, match="range"):
        merge(parts[:2])
    with pytest.raises(UserError, match="range"):
        merge([parts[1], parts[1], parts[2], parts[0]])


class Spy:
    """Counts act() calls and checks the hooks the runner promises."""

    name, version, privileged, weights_sha256 = "spy", "1", True, None

    def __init__(self):
        self.acts, self.bound, self.resets = 0, None, 0

    def bind(self, core):
        self.bound = core

    def reset(self, mask=None):
        self.resets += 1

    def act(self, obs):
        self.acts += 1
        return np.ones(obs.shape[0], np.int64)


class Recorder:
    def __init__(self):
        self.calls = []

    def begin_chunk(self, core, index):
        self.calls.append(("begin", index.tolist()))

    def record_step(self, core, modes, result):
        self.calls.append(("step", len(modes)))

    def end_chunk(self, core):
        self.calls.append(("end",))


def test_decision_interval_privileged_bind_and_recorder(tmp_path):
    path = suite_file(tmp_path / "k.toml", 6, decision_interval=5)
    suite = load_suite(path)
    spy, rec = Spy(), Recorder()
    r = run_suite(suite, spy, shard=(1, 2), chunk_size=2, progress=False, recorder=rec)
    steps = [c for c in rec.calls if c[0] == "step"]
    assert spy.bound is not None and spy.resets == 2
    assert [c for c in rec.calls if c[0] == "begin"] == [("begin", [3, 4]), ("begin", [5])]
    assert rec.calls.count(("end",)) == 2
    assert spy.acts == sum(-(-n // 5) for n in _chunk_steps(rec.calls))
    assert r.meta["range"] == [3, 6] and r.meta["decider"]["privileged"] and len(steps) == r.timing["steps"]


def _chunk_steps(calls):
    counts, n = [], 0
    for c in calls:
        if c[0] == "step":
            n += 1
        elif c[0] == "end":
            counts.append(n)
            n = 0
    return counts


@pytest.mark.parametrize("name", ["oncoming-8", "dense", "urban-50", "adversarial", "occluded"])
def test_scale_up_suites_run(name):
    suite = load_suite(name)
    r = run_suite(suite, zoo.load("always-overtake", suite.config), shard=(0, 200), progress=False)
    assert r.per["outcome"].shape == (suite.count // 200,) and np.all(r.per["outcome"] > 0)


@pytest.mark.parametrize("name", ["rule-fsm", "fuzzy", "dqn", "oracle", "ppo+shield"])
def test_dropping_finished_rows_gives_the_same_bits(tmp_path, monkeypatch, name):
    """The runner drops finished rows once at most half the batch runs; every per-scenario array
    (outcomes, safety metrics, abort timing) is the same as when it steps the whole batch."""
    from overtakezoo.benchmark.run import runner
    from overtakezoo.envs.core import OvertakeCore

    suite = small_suite(tmp_path, count=120)
    sizes = []
    real_clone = OvertakeCore.clone

    def clone(self, rows=None):
        out = real_clone(self, rows)
        sizes.append(out.num)
        return out

    monkeypatch.setattr(OvertakeCore, "clone", clone)
    runs = {}
    for floor in (10**9, 8):  # never, then down to 8 rows
        monkeypatch.setattr(runner, "MIN_COMPACT_ROWS", floor)
        sizes.clear()
        runs[floor] = run_suite(suite, zoo.load(name, config=suite.config), progress=False)
        if floor == 8 and name != "oracle":  # (the oracle's look-ahead clones too)
            assert sizes and all(
                2 * b <= a for a, b in zip([120, *sizes], sizes, strict=False)
            )  # it did shrink, by halves
    a, b = runs[10**9].per, runs[8].per
    assert a.keys() == b.keys()
    for key in a:
        assert np.array_equal(a[key], b[key], equal_nan=a[key].dtype.kind == "f"), key


def test_a_decider_without_declared_row_state_sees_the_whole_batch(tmp_path):
    """A decider whose per-row state is undeclared (an outside one) always gets every row."""
    seen = []

    class Outside(zoo.Decider):
        name = "outside"

        def act_batch(self, obs):
            seen.append(obs.shape[0])
            return np.full(obs.shape[0], 1, np.int64)

    run_suite(small_suite(tmp_path, count=100), Outside(), progress=False)
    assert set(seen) == {100}
