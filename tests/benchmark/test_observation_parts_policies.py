"""A policy that reads the v2v observation block: its card says so, and every evaluation (eval,
submit, verify, a pairing with a decider that does not read it) turns the block on for the road,
while the suite's settings and their hash stay the suite's."""

from __future__ import annotations

import json

import numpy as np
import pytest

from overtakezoo import zoo
from overtakezoo.benchmark.cli import main
from overtakezoo.benchmark.results.results import Results, config_sha256
from overtakezoo.benchmark.run.pairing import Pairing
from overtakezoo.benchmark.run.policy import load_policy
from overtakezoo.benchmark.run.runner import run_indices
from overtakezoo.envs import observation_layout, observation_size
from overtakezoo.envs.suites import load_suite
from overtakezoo.zoo.members.learned import read_parts
from overtakezoo.zoo.train.dqn import train

torch = pytest.importorskip("torch")


@pytest.fixture(scope="module")
def v2v_run(tmp_path_factory):
    """A short ps-dqn run on duel-train that reads the v2v block (`--set v2v=true`)."""
    out = tmp_path_factory.mktemp("v2v") / "run"
    overrides = {"v2v": True, "num_envs": 16, "learning_starts": 500, "log_every": 1000}
    train([load_suite("duel-train")], member="ps-dqn", steps=1500, seed=0, out=out, overrides=overrides, progress=False)
    return out


class Widths:
    """Records the width of every batch a decider is asked about."""

    def __init__(self, decider):
        self.inner, self.seen = decider, set()

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def act(self, obs):
        self.seen.add(np.asarray(obs).shape[1])
        return self.inner.act(obs)


def test_the_card_says_it_reads_v2v_and_the_runner_turns_the_block_on(v2v_run):
    card = json.loads((v2v_run / "ps-dqn.json").read_text())
    suite = load_suite("duel")
    assert card["observation"] == {"v2v": True} and "--set v2v=true" in card["reproduce"]
    policy = load_policy(str(v2v_run / "ps-dqn.json"), suite.config)
    assert (
        read_parts(policy) == {"v2v": True} and not suite.config.observation.v2v
    )  # the suite's own settings are untouched
    plain = observation_size(suite.config)
    width = plain + 2 * suite.config.observation.vehicles_per_lane * 3
    assert card["architecture"]["obs_dim"] == width
    alone = Widths(policy)
    run_indices(suite, alone, np.arange(6))
    assert alone.seen == {width}
    # Beside a decider without it, each reads its own observation: the road has the block.
    for seats in ((0, 1), (1, 0)):
        deciders = [
            Widths(load_policy(str(v2v_run / "ps-dqn.json"), suite.config)),
            Widths(zoo.load("fuzzy", suite.config)),
        ]
        by_av = [deciders[i] for i in seats]
        run_indices(suite, Pairing(by_av, suite.config.decision_interval), np.arange(6))
        assert deciders[0].seen == {width} and deciders[1].seen == {plain}
    assert "v2v" in observation_layout(policy.config)


def test_evaluated_submitted_and_verified_as_a_row(v2v_run, tiny_suite, tmp_path, capsys):
    tiny = tiny_suite(8, base="duel")
    results, root = tmp_path / "r.json", tmp_path / "lb"
    policy = str(v2v_run / "ps-dqn.npz")
    assert main(["eval", "--policy", policy, "--suite", tiny, "--out", str(results), "--no-progress"]) == 0
    row = Results.load(results)
    assert row.meta["config_sha256"] == config_sha256(load_suite(tiny).config)  # the suite's settings
    assert main(["submit", str(results), "--name", "v2v-dqn", "--policy", policy, "--root", str(root)]) == 0
    capsys.readouterr()
    assert main(["leaderboard", "--root", str(root), "--verify"]) == 0
    assert "verified submissions/tiny/v2v-dqn.json: 8 of 8" in capsys.readouterr().out
    # The card is what turns the block on: without its v2v entry the stored weights no longer fit.
    (card,) = (root / "submissions" / "artifacts").glob("*.json")
    edited = {k: v for k, v in json.loads(card.read_text()).items() if k != "observation"}
    card.write_text(json.dumps(edited))
    assert main(["leaderboard", "--root", str(root), "--verify"]) == 2


def test_partners_reading_different_parts_each_read_their_own_columns():
    # fuzzy reads its observation by layout: given its own columns of a road with both parts on, it
    # decides exactly as on the plain road.
    suite = load_suite("duel")
    plain = [zoo.load("fuzzy", suite.config) for _ in range(2)]
    parted = [zoo.load("fuzzy", suite.config.with_observation(**{part: True})) for part in ("v2v", "time_left")]
    pairing = Pairing(parted, suite.config.decision_interval)
    assert read_parts(pairing) == {"v2v": True, "time_left": True}
    idx = np.arange(10)
    want = run_indices(suite, Pairing(plain, suite.config.decision_interval), idx)
    got = run_indices(suite, pairing, idx)
    assert set(got) == set(want)
    for key in want:
        np.testing.assert_array_equal(got[key], want[key], err_msg=key)
