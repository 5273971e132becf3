"""One zoo decider drives several PettingZoo agents without mixing their state (``Decider.act_agents``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import overtakezoo.envs
from overtakezoo import zoo
from overtakezoo.benchmark.run.runner import run_indices
from overtakezoo.envs import parallel_env
from overtakezoo.envs.suites import load_suite


# ------------------------------------------------- one zoo decider, several PettingZoo agents
def _selfplay(env, decider, scenarios, act):
    """Every AV's outcome (AV-major, as the runner's arrays) with ``act(obs dict) -> actions``."""
    out = np.zeros((env.num_avs, scenarios.num), np.int64)
    for k in range(scenarios.num):
        obs, _ = env.reset(options={"scenarios": scenarios.take([k])})
        decider.reset_agents()
        while env.agents:
            obs, _, term, trunc, infos = env.step(act(obs))
            for agent in infos:
                if term[agent] or trunc[agent]:
                    out[int(agent[3:]), k] = infos[agent]["outcome"]
    return out.reshape(-1)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_act_agents_drives_a_duel_as_the_runners_self_play(seed):
    """rule-fsm (stateful: it counts ticks per row) driving both AVs of parallel_env("duel") through
    act_agents ends every road as the benchmark runner's self-play does, on the same scenarios."""
    suite = dataclasses.replace(load_suite("duel"), seed=seed, count=10)
    ref = run_indices(suite, zoo.load("rule-fsm", suite.config), np.arange(suite.count), safety=False)
    env = parallel_env("duel", hold_steps=1)  # the runner holds rule-fsm's decisions 1 core step (a suite's env: 10)
    decider = zoo.load("rule-fsm", env.config)
    got = _selfplay(env, decider, suite.scenarios(), decider.act_agents)
    np.testing.assert_array_equal(got, ref["outcome"])


def test_single_observation_act_mixes_the_agents_state():
    """What act_agents is for: one stateful decider asked one agent at a time shares one row of state
    between the agents, and the duel ends otherwise."""
    suite = load_suite("duel")
    ref = run_indices(suite, zoo.load("rule-fsm", suite.config), np.arange(20), safety=False)["outcome"]
    env = parallel_env("duel", hold_steps=1)
    decider = zoo.load("rule-fsm", env.config)
    mixed = _selfplay(
        env, decider, suite.scenarios().take(np.arange(20)), lambda obs: {a: decider.act(o) for a, o in obs.items()}
    )
    assert (mixed != ref).any()


def test_act_agents_rows_are_stable_per_agent_and_reset_per_episode():
    calls = []

    class Echo(zoo.Decider):
        """Records each batch; mode = the row's first feature rounded."""

        def act_batch(self, obs):
            calls.append(obs.copy())
            return obs[:, 0].round().astype(np.int64)

    d = Echo()
    width = overtakezoo.envs.observation_size(d.config)
    o = {a: np.full(width, v, np.float32) for a, v in (("av_0", 0.0), ("av_1", 1.0), ("av_2", 2.0))}
    assert d.act_agents(o) == {"av_0": 0, "av_1": 1, "av_2": 2}
    assert d.act_agents({"av_2": o["av_2"], "av_0": o["av_0"]}) == {"av_2": 2, "av_0": 0}  # av_1 left
    np.testing.assert_array_equal(calls[-1][:, 0], [0.0, 1.0, 2.0])  # its row kept its last observation
    with pytest.raises(KeyError, match="'av_9' is not one of this episode's agents"):
        d.act_agents({"av_9": o["av_0"]})
    assert d.act_agents({"av_1": o["av_2"]}) == {"av_1": 2}  # av_1 is back: a new episode, new rows
    assert calls[-1].shape[0] == 1
    d.reset_agents()
    assert d.act_agents(o) == {"av_0": 0, "av_1": 1, "av_2": 2} and calls[-1].shape[0] == 3
