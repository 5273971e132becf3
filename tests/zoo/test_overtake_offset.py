"""A learned member's OVERTAKE threshold (the card's ``overtake_offset``, chosen on training splits by
``overtakezoo decision-rate --overtake-offsets``): it shifts the OVERTAKE score before the argmax, so a
lower one overtakes less; results and cross-play tables tell it apart; a bad value is refused."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import jsonschema
import numpy as np
import pytest

from overtakezoo.benchmark.cli import main
from overtakezoo.benchmark.run.runner import run_suite
from overtakezoo.envs import SUCCESS
from overtakezoo.envs.suites import load_suite
from overtakezoo.zoo.members.learned import PRETRAINED, MLPDecider, WeightsError, describe, load_weights, read_card
from overtakezoo.zoo.train.contract import CARD_SCHEMA

SCHEMA = json.loads(CARD_SCHEMA.read_text())


@pytest.fixture(scope="module")
def ppo_parts():
    card = read_card(PRETRAINED / "ppo.json", "ppo")
    card.pop("overtake_offset", None)
    return load_weights(PRETRAINED / card["weights_file"], card, "ppo"), card


def test_a_lower_offset_overtakes_less_and_names_itself(ppo_parts):
    net, card = ppo_parts
    suite = load_suite("table1")
    plain = MLPDecider(net, "ppo", suite.config, card)
    zero = MLPDecider(net, "ppo", suite.config, {**card, "overtake_offset": 0.0})
    assert zero.version == plain.version  # 0 is the card without one
    obs = np.random.default_rng(0).normal(size=(512, net.in_features))
    np.testing.assert_array_equal(zero.act_batch(obs), plain.act_batch(obs))
    results, opposite = {}, {}
    for offset in (0.0, -1.0, -50.0):
        decider = MLPDecider(net, "ppo", suite.config, {**card, "overtake_offset": offset})
        results[offset] = run_suite(suite, decider, progress=False, limit=60)
        opposite[offset] = float(results[offset].per["opposite_time"].sum())  # seconds in the opposite lane
        if offset:
            assert decider.version.endswith(f".overtake{offset:+g}") and decider.version != plain.version
    assert opposite[0.0] > opposite[-1.0] > opposite[-50.0] == 0.0
    # -50 never starts an overtake: no pass, so no success and no crash in the opposite lane
    assert (results[-50.0].per["outcome"] != SUCCESS).all()
    assert (results[0.0].per["outcome"] == SUCCESS).mean() > 0.8


def test_the_description_and_schema_take_it(ppo_parts):
    _, card = ppo_parts
    assert "-0.75 on the OVERTAKE score" in describe("ppo", {**card, "overtake_offset": -0.75})
    assert "OVERTAKE score" not in describe("ppo", card)
    jsonschema.validate({**card, "overtake_offset": -0.75}, SCHEMA, cls=jsonschema.Draft202012Validator)


@pytest.mark.parametrize("bad", [51, -50.5, "x", True, None, [0.5], math.nan, math.inf])
def test_a_bad_offset_is_refused_naming_the_key(ppo_parts, bad):
    net, card = ppo_parts
    with pytest.raises(WeightsError, match="overtake_offset"):
        MLPDecider(net, "ppo", None, {**card, "overtake_offset": bad})
    if not (isinstance(bad, float) and not math.isfinite(bad)):  # a JSON card cannot hold NaN or inf
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate({**card, "overtake_offset": bad}, SCHEMA, cls=jsonschema.Draft202012Validator)


def test_the_command_chooses_the_offset_on_training_splits(tmp_path, ppo_parts):
    """``overtakezoo decision-rate --overtake-offsets`` on two runs (the shipped ppo under two seeds) over a
    small training split: the best mean score wins (ties: nearest 0), written into each run's card,
    which keeps its decision rate."""
    split = tmp_path / "table1-mini-train.toml"
    split.write_text('name = "table1-mini-train"\nversion = 1\nbase = "table1"\ncount = 30\nseed = 7\n')
    _, card = ppo_parts
    runs = []
    for seed in (0, 1):
        run = tmp_path / f"ppo-s{seed}"
        run.mkdir()
        shutil.copy(PRETRAINED / "ppo.npz", run / "ppo.npz")
        (run / "ppo.json").write_text(json.dumps({**card, "seed": seed}))
        runs.append(str(run))
    assert main(["decision-rate", "ppo", *runs, "--overtake-offsets=-50,0,-1", "--train-suite", str(split)]) == 0
    cards = [json.loads((Path(r) / "ppo.json").read_text()) for r in runs]
    sel = cards[0]["overtake_offset_selection"]
    assert sel == cards[1]["overtake_offset_selection"] and sel["candidates"] == [0.0, -1.0, -50.0]
    assert sel["per_seed"]["0"] == sel["per_seed"]["1"]  # the same weights score the same
    assert sel["mean"]["-50.0"] == 0.0  # never overtaking scores 0
    best = max(sel["candidates"], key=lambda o: (sel["mean"][str(o)], -abs(o)))
    assert sel["chosen"] == best and all(c.get("overtake_offset", 0.0) == best for c in cards)
    for c in cards:
        assert c.get("decide_every") == card.get("decide_every")  # the rate stays as it was
        jsonschema.validate(c, SCHEMA, cls=jsonschema.Draft202012Validator)
        assert MLPDecider(load_weights(PRETRAINED / "ppo.npz", c, "ppo"), "ppo", None, c).overtake_offset == best

    # The same choice from worker processes, run as a user runs the command: --jobs 2 writes the same table.
    for seed, run in enumerate(runs):
        (Path(run) / "ppo.json").write_text(json.dumps({**card, "seed": seed}))
    subprocess.run(
        [
            sys.executable,
            "-m",
            "overtakezoo.benchmark.cli",
            "decision-rate",
            "ppo",
            *runs,
            "--overtake-offsets=-50,0,-1",
            "--train-suite",
            str(split),
            "--jobs",
            "2",
        ],
        check=True,
        capture_output=True,
        text=True,
    )
    assert json.loads((Path(runs[0]) / "ppo.json").read_text())["overtake_offset_selection"] == sel


def test_choosing_the_rate_takes_out_a_threshold_chosen_at_another_rate(tmp_path, ppo_parts):
    """The shipped ppo (rate and threshold chosen) beside a run without a threshold: the rate stage scores
    both with no threshold (the same weights score the same) and leaves neither card with one."""
    split = tmp_path / "table1-mini-train.toml"
    split.write_text('name = "table1-mini-train"\nversion = 1\nbase = "table1"\ncount = 20\nseed = 7\n')
    _, card = ppo_parts
    chosen = {**card, "overtake_offset": -1.0}  # (a threshold chosen at the card's rate)
    runs = []
    for seed, c in enumerate([chosen, {k: v for k, v in card.items() if not k.startswith("overtake_offset")}]):
        run = tmp_path / f"ppo-s{seed}"
        run.mkdir()
        shutil.copy(PRETRAINED / "ppo.npz", run / "ppo.npz")
        (run / "ppo.json").write_text(json.dumps({**c, "seed": seed}))
        runs.append(str(run))
    assert main(["decision-rate", "ppo", *runs, "--candidates", "5,1", "--train-suite", str(split)]) == 0
    cards = [json.loads((Path(r) / "ppo.json").read_text()) for r in runs]
    sel = cards[0]["decide_every_selection"]
    assert sel["per_seed"]["0"] == sel["per_seed"]["1"]
    assert not any("overtake_offset" in c or "overtake_offset_selection" in c for c in cards)
