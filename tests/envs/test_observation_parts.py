"""The opt-in observation parts: ``v2v`` (per vehicle slot, is it an AV and is that AV overtaking or
aborting) and ``time_left`` (the share of the time limit left). Off (the default) the observation
is what it always was; on, they are appended and every other feature keeps its place and its bits,
on every backend."""

from __future__ import annotations

import numpy as np
import pytest

from overtakezoo.envs import (
    ConfigError,
    EnvConfig,
    OvertakeCore,
    make_scenario,
    observation_layout,
    observation_size,
    parallel_env,
)
from overtakezoo.envs.config import ABORT, FOLLOW, OVERTAKE
from overtakezoo.envs.suites import load_suite

KMH = 1 / 3.6


def _with_v2v(config: EnvConfig) -> EnvConfig:
    return EnvConfig.from_dict({**config.to_dict(), "observation": {**config.to_dict()["observation"], "v2v": True}})


def test_time_left_counts_down_to_the_limit_inside_the_space():
    par = parallel_env("duel", observation={"time_left": True, "v2v": True})
    obs, _ = par.reset(seed=3)
    last = observation_layout(par.config)["time_left"]
    assert last.stop == observation_size(par.config) and all(o[last] == 1.0 for o in obs.values())
    limit = float(par.core.scen.time_limit[0])
    while par.agents:
        obs, *_ = par.step({a: FOLLOW for a in par.agents})
        for agent, o in obs.items():
            assert par.observation_space(agent).contains(o)
            np.testing.assert_allclose(o[last], max(0.0, (limit - float(par.core.t[0])) / limit), atol=1e-6)


def _v2v_slots(config, obs):
    """(lane, slot, [is AV, overtaking, aborting]) of one observation."""
    return obs[observation_layout(config)["v2v"]].reshape(2, config.observation.vehicles_per_lane, 3)


def _vehicle_slots(config, obs, lane):
    return obs[observation_layout(config)[lane]].reshape(config.observation.vehicles_per_lane, 5)


def test_off_by_default_and_checked():
    assert not {"v2v", "time_left"} & set(observation_layout(EnvConfig()))
    for part in ("v2v", "time_left"):
        with pytest.raises(ConfigError, match=f"observation.{part}"):
            EnvConfig.from_dict({"observation": {part: "yes"}})


def test_av_1_reads_that_av_0_pulls_out_and_npcs_are_not_avs():
    # av_0 15 m behind a slow lead; av_1 oncoming 40 m ahead, 10 m behind its own lead: av_1 sees
    # av_0, av_0's lead and its own lead, and only av_0 is an AV.
    par = parallel_env(scenario={"oncoming_av": 1, "oncoming_count": 0}, observation={"v2v": True})
    scenario = make_scenario(lead=(15.0, 1.0), oncoming_av=(40.0, 15 * KMH, 10.0, 1.0), goal=150.0)
    par.reset(options={"scenarios": scenario})
    cfg = par.config
    for mode, flags in ((FOLLOW, [1.0, 0.0, 0.0]), (OVERTAKE, [1.0, 1.0, 0.0])):
        obs, *_ = par.step({"av_0": mode, "av_1": FOLLOW})
        v2v = _v2v_slots(cfg, obs["av_1"]).reshape(-1, 3)
        present = np.concatenate(
            [_vehicle_slots(cfg, obs["av_1"], lane)[:, 0] for lane in ("ego_lane", "opposite_lane")]
        )
        assert present.sum() == 3
        assert v2v[present == 1].tolist().count(flags) == 1, mode  # av_0, broadcasting its mode
        assert v2v[present == 1].tolist().count([0.0, 0.0, 0.0]) == 2  # the two leads: NPCs broadcast nothing
        assert not v2v[present == 0].any()  # empty slots stay zero


@pytest.mark.parametrize("name", ["platoon", "mixed-traffic"])
def test_on_keeps_every_other_feature_bit_for_bit_on_every_backend(name):
    suite = load_suite(name)
    on = _with_v2v(suite.config)
    scenarios = suite.scenarios().take(np.arange(24))
    rng = np.random.default_rng(7)
    torch = pytest.importorskip("torch")
    cores = [OvertakeCore(suite.config), OvertakeCore(on)]
    cores += [OvertakeCore(on, backend="torch", sync_free=sync_free) for sync_free in (False, True)]
    outs = [[np.asarray(c.reset(scenarios))] for c in cores]
    for _ in range(40):
        modes = rng.choice([FOLLOW, OVERTAKE, ABORT], size=cores[0].num, p=[0.6, 0.3, 0.1])
        for c, out in zip(cores, outs, strict=True):
            out.append(np.asarray(c.step(torch.as_tensor(modes) if c.xp.name == "torch" else modes).obs))
    base, block = np.concatenate(outs[0]), np.concatenate(outs[1])
    width = base.shape[1]
    assert np.array_equal(block[:, :width], base)
    for out in outs[2:]:
        assert np.array_equal(np.concatenate(out), block)
    v2v = block[:, width:].reshape(-1, 3)
    assert {(1.0, 0.0, 0.0), (1.0, 1.0, 0.0)} <= {tuple(row) for row in v2v.tolist()}  # AVs following, overtaking
    assert (v2v[:, 1:].sum(-1) <= v2v[:, 0]).all()  # only an AV broadcasts a mode
