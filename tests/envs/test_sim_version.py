"""Reference trajectories pin the simulator's behaviour to SIM_VERSION.

Leaderboard rows are re-run (``leaderboard --verify``) and marked stale by simulator version, so a
behaviour change that keeps SIM_VERSION would silently invalidate every row. These trajectories
(the final state of a few table1-reactive scenarios (table1 v1) under two fixed deciders) fail on any such change.
"""

import hashlib
import json

import numpy as np
import pytest

from overtakezoo import zoo
from overtakezoo.benchmark.run.runner import run_suite
from overtakezoo.envs import SIM_VERSION
from overtakezoo.envs.suites import load_suite

# SIM_VERSION -> decider -> (per-scenario (outcome, steps), sha256 of the final states rounded to 1e-6).
REFERENCE = {
    1: {
        "rule-fsm": (
            [(1, 251), (1, 242), (1, 384), (1, 247), (1, 244), (1, 254)],
            "9bee66539b8fe8d2a83759ca0e97646590003e59c5bb548963a648e7a8fa371b",
        ),
        "always-overtake": (
            [(1, 248), (1, 242), (2, 134), (1, 245), (1, 242), (1, 250)],
            "ae569e52e41398326f8ef65b49648d523b46bd42ae64968b8b6ccf5e6e137067",
        ),
    },
}
# 2: the observation gained the speed limit and the sensor range; the rule deciders' trajectories are
# those of version 1.
REFERENCE[2] = REFERENCE[1]
SCENARIOS = 6  # table1-reactive scenarios 0..5


class FinalState:
    """A runner recorder that keeps each chunk's final state."""

    def __init__(self):
        self.states = []

    def begin_chunk(self, core, index):
        pass

    def record_step(self, core, modes, result):
        pass

    def end_chunk(self, core):
        keys = ("x", "y", "v", "psi", "t", "outcome", "episode_steps", "_npc_s", "_npc_v")
        self.states.append({k: np.round(np.asarray(getattr(core, k), dtype=np.float64), 6).tolist() for k in keys})


def trajectory(decider):
    suite = load_suite("table1-reactive")  # table1 v1: the suite these were recorded on
    rec = FinalState()
    run_suite(suite, zoo.load(decider, suite.config), progress=False, recorder=rec, limit=SCENARIOS)
    (state,) = rec.states
    steps = [(int(o), int(n)) for o, n in zip(state["outcome"], state["episode_steps"], strict=True)]
    return steps, hashlib.sha256(json.dumps(state, sort_keys=True).encode()).hexdigest()


@pytest.mark.parametrize("decider", ["rule-fsm", "always-overtake"])
def test_reference_trajectories_match_sim_version(decider):
    assert SIM_VERSION in REFERENCE, f"no reference trajectories for SIM_VERSION {SIM_VERSION}: record them"
    want_steps, want_hash = REFERENCE[SIM_VERSION][decider]
    steps, digest = trajectory(decider)
    hint = (
        f"{decider} on table1-reactive scenarios 0-{SCENARIOS - 1} no longer follows the SIM_VERSION {SIM_VERSION} "
        "trajectories: the simulator's behaviour changed. Bump SIM_VERSION (envs/version.py) and re-measure "
        "the leaderboard (scripts/reproduce-leaderboard.sh), then record the new reference here"
    )
    assert steps == want_steps, f"{hint}; (outcome, steps) now {steps}"
    assert digest == want_hash, f"{hint}; final-state sha256 now {digest}"
