"""Held-out driver populations: suites on the same roads that differ only in the drivers, and the
board's table of each member against them (benchmark/leaderboard/drivers.py)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from overtakezoo.benchmark.leaderboard.generate import generate
from overtakezoo.benchmark.suite_groups import CORE, DRIVER_FAMILIES, DRIVERS, MULTI, driver_suite
from overtakezoo.envs.suites import load_suite

REPO_LEADERBOARDS = Path(__file__).resolve().parents[2] / "leaderboards"
# What a population may change: how the NPCs drive (never where the roads put them).
DRIVER_ARRAYS = {"npc_behaviour", "npc_boost", "npc_reaction"}


@pytest.mark.parametrize("family", sorted(DRIVER_FAMILIES))
def test_every_population_of_a_family_meets_the_same_roads(family):
    standard = load_suite(f"{family}-standard")
    base = load_suite(DRIVER_FAMILIES[family])
    assert standard.distribution == base.distribution and standard.config == base.config  # the training drivers
    roads = standard.scenarios().to_arrays()
    for population in DRIVERS:
        suite = load_suite(f"{family}-{population}")
        assert driver_suite(suite.name) == (family, population)
        assert (suite.seed, suite.count, suite.num_avs) == (
            standard.seed,
            standard.count,
            base.num_avs,
        )
        got = suite.scenarios().to_arrays()
        differ = {k for k, v in roads.items() if not np.array_equal(v, got[k])}
        assert differ <= DRIVER_ARRAYS, (suite.name, differ)
        assert bool(suite.config.npc != standard.config.npc or differ) == (population != "standard"), suite.name


def test_held_out_drivers_drive_differently_from_the_training_ones():
    npc = {p: load_suite(f"drivers-{p}").config.npc for p in DRIVERS}
    assert npc["timid"].time_headway > npc["standard"].time_headway > npc["aggressive"].time_headway
    assert npc["timid"].max_acceleration < npc["standard"].max_acceleration < npc["aggressive"].max_acceleration
    slow = load_suite("drivers-slow").scenarios().npc_reaction
    standard = load_suite("drivers-standard").scenarios().npc_reaction
    assert slow.min() > standard.max()
    assert (load_suite("drivers-gap-closer").scenarios().npc_boost[:, 0] > 0).all()


def test_the_drivers_table_puts_training_beside_held_out_and_leaves_the_score_alone(tmp_path):
    root = tmp_path / "lb"  # the shipped rows of three members on every population, and two core suites
    names = ("rule-fsm", "fuzzy", "oracle")
    suites = ["table1", "oncoming-2", *(f"{f}-{p}" for f in DRIVER_FAMILIES for p in DRIVERS)]
    for suite in suites:
        (root / "submissions" / suite).mkdir(parents=True)
        for name in names:
            row = REPO_LEADERBOARDS / "submissions" / suite / f"{name}.json"
            if row.is_file():
                shutil.copy(row, root / "submissions" / suite)
    files = generate(root)
    index = json.loads(files["index.json"])
    assert not {s for s in index["suites"] if driver_suite(s)}  # never among the ranked suites
    assert not {s for s in index.get("multi_agent", {}) if driver_suite(s)} and set(MULTI).isdisjoint(suites)
    single = index["drivers"]["families"]["drivers"]
    assert set(single["members"]) == set(names)
    for name, m in single["members"].items():
        rows = m["populations"]
        held = sum(rows[p]["success"] for p in DRIVERS if DRIVERS[p] == "held-out") / 4
        assert m["held_out_success"] == pytest.approx(held)
        assert m["change_points"] == round(100 * (held - rows["standard"]["success"]), 1)
        assert m["privileged"] == (name == "oracle")
    page = files["drivers.md"].decode()
    assert "(train): success" in page and page.count("(held-out): success") == 4 * len(index["drivers"]["families"])
    assert "| oracle (upper bound) |" in page
    assert "## Other drivers (held-out populations)" in files["README.md"].decode()
    # The score is the core suites' alone: the same without the drivers rows.
    for suite in suites[2:]:
        shutil.rmtree(root / "submissions" / suite)
    alone = json.loads(generate(root)["index.json"])
    assert "drivers" not in alone and alone["headline"] == index["headline"] and set(CORE) >= set(alone["suites"])
