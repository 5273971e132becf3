"""CONTRIBUTING.md's checklist for a new suite, followed once in a scratch copy of the built-in
suites: two new files (a variant with a base and its training split) and nothing else make a suite
that is listed, registered as an env id, evaluated and trained on; putting it in the score is one
name in ``CORE`` (``benchmark/suite_groups.py``), after which the core mixture trains on its split
and the headline refuses a learned member's seeds that do not cover it, rather than dropping to one run."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import gymnasium
import pettingzoo
import pytest

from overtakezoo.benchmark import suite_groups
from overtakezoo.benchmark.cli import main
from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.leaderboard.headline import build_table, load_seeds
from overtakezoo.benchmark.results.results import Results
from overtakezoo.envs import suites
from overtakezoo.envs.faces.gym import register_envs

LEADERBOARDS = Path(__file__).resolve().parents[2] / "leaderboards"
VARIANT = b"""name = "late"
version = 1
base = "table1-reactive"
count = 12
seed = 424242
description = "table1-reactive with oncoming vehicles revealed late"
[scenario]
sensor_range = 30.0
"""
SPLIT = b'name = "late-train"\nversion = 1\nbase = "late"\ncount = 6\nseed = 424243\n'


@pytest.fixture
def with_late(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """Step 1: the suite's own files, in a copy of the built-in folder."""
    folder = tmp_path / "suites"
    shutil.copytree(suites.SUITES_DIR, folder)
    (folder / "late.toml").write_bytes(VARIANT)
    (folder / "late-train.toml").write_bytes(SPLIT)
    monkeypatch.setattr(suites, "SUITES_DIR", folder)
    return folder


def test_a_new_suite_is_listed_registered_evaluated_and_trained_on(with_late, tmp_path, capsys):
    assert {"late", "late-train"} <= set(suites.suite_names())
    assert main(["suites"]) == 0
    assert "late" in capsys.readouterr().out
    register_envs()  # (what `import overtakezoo.envs` does in a new process)
    try:
        env = gymnasium.make("overtakezoo/late-v1")
        env.reset(seed=0)
        assert env.unwrapped.hold_steps == 10  # the zoo's 1 s, as every suite id
        env.close()
    finally:
        gymnasium.registry.pop("overtakezoo/late-v1", None)
        for registry in ("parallel_registry", "aec_registry"):
            getattr(pettingzoo, registry, {}).pop("overtakezoo/late-v1", None)
    out = tmp_path / "late.json"
    assert main(["eval", "--suite", "late", "--decider", "rule-fsm", "--out", str(out), "--no-progress"]) == 0
    results = Results.load(out)
    assert results.suite["hash"] == suites.load_suite("late").hash and len(results.per_scenario_array("outcome")) == 12
    assert [s.name for s in suite_groups.load_training("late-train")] == ["late-train"]


def test_putting_it_in_the_score_is_one_name_and_refuses_seeds_that_miss_it(with_late, tmp_path, monkeypatch):
    monkeypatch.setattr(suite_groups, "CORE", (*suite_groups.CORE, "late"))  # step 2
    assert suite_groups.mixtures()["core-train"][-1] == "late-train"  # the core mixture follows
    out = tmp_path / "dqn.json"
    assert main(["eval", "--suite", "late", "--decider", "dqn", "--out", str(out), "--no-progress"]) == 0
    late = Results.load(out)
    seeds = load_seeds(LEADERBOARDS)  # the shipped seeds files, evaluated before `late` existed
    with pytest.raises(UserError, match=r"^seeds/dqn.json: seed \d+ has no result on the scoring suite late "):
        build_table({"dqn": {"late": late.summary}}, seeds, {"late": late.suite["hash"]})
    # Once every seed is evaluated there (`overtakezoo seeds dqn RUN_DIRS`), the member keeps its seeds.
    doc = json.loads(json.dumps(seeds["dqn"]))
    s, c = late.summary["success_rate"], late.summary["crash_rate"]
    for entry in doc["seeds"]:
        entry["suites"]["late"] = {"n": s["n"], "success": s["k"], "crash": c["k"], "suite_sha256": late.suite["hash"]}
    table = build_table({"dqn": {"late": late.summary}}, {"dqn": doc}, {"late": late.suite["hash"]})
    assert len(table["dqn"]["late"]) == len(doc["seeds"]) > 1
