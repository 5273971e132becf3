"""A learned member's deployed decision rate (the card's ``decide_every``, chosen on training splits by
``overtakezoo decision-rate``): the runner re-asks the member that often, results and cross-play tables
tell the rate apart, and a card with a bad rate is refused, never guessed."""

from __future__ import annotations

import copy
import json
import shutil
from pathlib import Path

import jsonschema
import numpy as np
import pytest

from overtakezoo.benchmark.cli import main
from overtakezoo.benchmark.run.runner import run_suite
from overtakezoo.envs.suites import load_suite
from overtakezoo.zoo.members.learned import (
    PRETRAINED,
    MLPDecider,
    WeightsError,
    deployed_repeat,
    describe,
    load_weights,
    read_card,
)
from overtakezoo.zoo.train.contract import CARD_SCHEMA

SCHEMA = json.loads(CARD_SCHEMA.read_text())


@pytest.fixture(scope="module")
def dqn_parts():
    card = read_card(PRETRAINED / "dqn.json", "dqn")
    card.pop("decide_every", None)  # the training hold: 10 core steps
    return load_weights(PRETRAINED / card["weights_file"], card, "dqn"), card


def counting(decider: MLPDecider) -> list[int]:
    calls: list[int] = []
    inner = decider.act_batch

    def act_batch(obs: np.ndarray) -> np.ndarray:
        calls.append(len(obs))
        return inner(obs)

    decider.act_batch = act_batch
    return calls


def test_the_runner_re_asks_the_member_at_its_deployed_rate(dqn_parts):
    net, card = dqn_parts
    suite = load_suite("occluded")
    held = MLPDecider(net, "dqn", suite.config, card)
    every = MLPDecider(net, "dqn", suite.config, {**card, "decide_every": 1})
    assert (held.action_repeat, every.action_repeat) == (10, 1)
    calls_held, calls_every = counting(held), counting(every)
    a = run_suite(suite, held, progress=False, limit=40)
    b = run_suite(suite, every, progress=False, limit=40)
    # About ten times the decisions over the same episodes (each runs to its end).
    assert 7 * len(calls_held) < len(calls_every) <= 10 * len(calls_held) + 10
    # and a different driver: the version names the rate, so a results file or cross-play cell
    # measured at one rate is never taken for the other
    assert held.version != every.version and every.version.endswith(".every1")
    assert a.per["outcome"].shape == b.per["outcome"].shape


def test_the_card_and_its_description_say_both_rates(dqn_parts):
    _, card = dqn_parts
    text = describe("dqn", {**card, "decide_every": 1})
    assert "held 10 steps in training, re-decided every 1" in text
    assert "re-decided" not in describe("dqn", card)
    jsonschema.validate({**card, "decide_every": 1}, SCHEMA, cls=jsonschema.Draft202012Validator)


@pytest.mark.parametrize("bad", [0, -1, 1001, 2.5, "1", True, None])
def test_a_bad_rate_is_refused_naming_the_key(dqn_parts, bad):
    net, card = dqn_parts
    with pytest.raises(WeightsError, match="decide_every"):
        MLPDecider(net, "dqn", None, {**card, "decide_every": bad})
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({**card, "decide_every": bad}, SCHEMA, cls=jsonschema.Draft202012Validator)


def test_a_network_with_memory_keeps_its_training_rate(dqn_parts):
    _, card = dqn_parts
    stacked = copy.deepcopy(card)
    stacked["frame_stack"] = 4
    with pytest.raises(WeightsError, match="frame-stacked"):
        deployed_repeat("dagger", {**stacked, "decide_every": 1})
    assert deployed_repeat("dagger", stacked) == 10


def test_the_command_chooses_on_training_splits_and_writes_every_run_card(tmp_path):
    """``overtakezoo decision-rate`` on two runs (the shipped dqn under two seeds) over a small training
    split: the chosen rate is the best mean score, written with its table into each run's card."""
    split = tmp_path / "occluded-mini-train.toml"
    split.write_text('name = "occluded-mini-train"\nversion = 1\nbase = "occluded"\ncount = 30\nseed = 7\n')
    runs = []
    for seed in (0, 1):
        run = tmp_path / f"dqn-s{seed}"
        run.mkdir()
        shutil.copy(PRETRAINED / "dqn.npz", run / "dqn.npz")
        card = json.loads((PRETRAINED / "dqn.json").read_text())
        card.pop("decide_every", None)
        card["seed"] = seed
        (run / "dqn.json").write_text(json.dumps(card))
        runs.append(str(run))
    assert main(["decision-rate", "dqn", *runs, "--candidates", "10,1", "--train-suite", str(split)]) == 0
    cards = [json.loads((Path(r) / "dqn.json").read_text()) for r in runs]
    sel = cards[0]["decide_every_selection"]
    assert sel == cards[1]["decide_every_selection"] and sel["candidates"] == [10, 1]
    assert sel["per_seed"]["0"] == sel["per_seed"]["1"]  # the same weights score the same
    best = max((10, 1), key=lambda k: (sel["mean"][str(k)], k))
    assert sel["chosen"] == best and all(c.get("decide_every", 10) == best for c in cards)
    for card in cards:  # still a valid card, loading at the chosen rate
        jsonschema.validate(card, SCHEMA, cls=jsonschema.Draft202012Validator)
        assert MLPDecider(load_weights(PRETRAINED / "dqn.npz", card, "dqn"), "dqn", None, card).action_repeat == best
