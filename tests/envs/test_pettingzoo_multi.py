"""The PettingZoo face on multi-AV roads: PettingZoo's own tests on the multi-AV suites, agents that
meet (see and crash into each other), finished agents, SuperSuit's parameter-sharing route with a
short PPO run, and the core's batch (N roads x E AV rows) matching the env road by road."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

with warnings.catch_warnings():  # pettingzoo.test imports its own example envs through a deprecated path
    warnings.simplefilter("ignore", DeprecationWarning)
    from pettingzoo.test import parallel_api_test, parallel_seed_test

from overtakezoo.benchmark.suite_groups import MULTI
from overtakezoo.envs import ConfigError, OvertakeCore, make_scenario, observation_layout, parallel_env, sb3_vec_env
from overtakezoo.envs.config import OVERTAKE
from overtakezoo.envs.faces.spaces import ego_observation_space
from overtakezoo.envs.suites import load_suite

KMH = 1 / 3.6
# With NPC agents PettingZoo's checker notes that AVs and NPCs observe different sizes.
NPC_WARNINGS = ("different shapes", "different observation space sizes")


def _unexpected(caught, allowed=()) -> list[str]:
    return [str(w.message) for w in caught if not any(a in str(w.message) for a in allowed)]


def duel(distance: float = 100.0, lead_gap: float = 15.0, oncoming_lead_gap: float = 30.0):
    """av_0 behind its lead (15 m, 1 m/s) in lane 0; av_1, ``distance`` m from av_0's front, drives
    towards -s in lane 1 behind its own lead (1 m/s); both goals 150 m from their starts."""
    return make_scenario(lead=(lead_gap, 1.0), oncoming_av=(distance, 15 * KMH, oncoming_lead_gap, 1.0), goal=150.0)


def duel_env(**kwargs):
    # The distribution only sets the road's layout (two AVs, two NPC slots); each test starts on duel().
    return parallel_env(scenario={"oncoming_av": 1, "oncoming_count": 0}, **kwargs)


# ---------------------------------------------------------------- PettingZoo's own tests
@pytest.mark.parametrize("name", ["duel", "platoon"])
@pytest.mark.parametrize("npc_agents", [False, True])
def test_parallel_api_test_on_multi_suites(name, npc_agents):
    par = parallel_env(load_suite(name), npc_agents=npc_agents)
    avs = [f"av_{e}" for e in range(load_suite(name).scenarios().num_avs)]
    assert par.possible_agents[: len(avs)] == avs
    npcs = par.possible_agents[len(avs) :]
    assert all(a.startswith("npc_") for a in npcs) and bool(npcs) == npc_agents
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        parallel_api_test(par, num_cycles=300)
    assert _unexpected(caught, NPC_WARNINGS if npc_agents else ()) == []


@pytest.mark.parametrize("name", ["duel", "platoon"])
@pytest.mark.parametrize("npc_agents", [False, True])
def test_parallel_seed_test_on_multi_suites(name, npc_agents):
    suite = load_suite(name)
    parallel_seed_test(lambda: parallel_env(suite, npc_agents=npc_agents))


def test_built_from_a_suite_or_its_config_or_a_dict():
    suite = load_suite("duel")
    a, b = parallel_env(suite), parallel_env(suite=suite, decision_interval=2)
    c = parallel_env(suite.config)
    d = parallel_env(suite.config.to_dict())
    assert a.config == c.config == d.config == suite.config and b.config.decision_interval == 2
    for par in (a, c, d):
        par.reset(seed=4)
    np.testing.assert_array_equal(a.core.scen.av_s, suite.distribution.sample(1, 4).av_s)  # the env's seed
    np.testing.assert_array_equal(a.core.scen.npc_s, c.core.scen.npc_s)
    assert parallel_env("duel").config == suite.config  # a suite's name is loaded
    with pytest.raises(ConfigError, match="not both"):
        parallel_env(suite.config, suite=suite)
    with pytest.raises(ValueError, match="2 automated vehicles"):
        parallel_env().reset(options={"scenarios": duel()})


def test_every_av_has_the_same_spaces_and_stays_in_them():
    """Parameter sharing needs one space for every AV; the core's own (unclipped) observations of
    random play on every multi suite lie in it, for every AV row."""
    for name in MULTI:
        suite = load_suite(name)
        par = parallel_env(suite)
        avs = [a for a in par.possible_agents if a.startswith("av_")]
        assert len({id(par.observation_space(a)) for a in avs}) == 1
        assert len({id(par.action_space(a)) for a in avs}) == 1
        space = ego_observation_space(suite.config)
        core = OvertakeCore(suite.config)
        obs = core.reset(suite.scenarios().take(slice(0, 24)))
        rng = np.random.default_rng(11)
        modes = rng.integers(0, 3, core.num)
        step = 0
        while not core.done.all():
            bad = ~((obs >= space.low) & (obs <= space.high)).all(axis=1)
            assert not bad.any(), (name, step, np.flatnonzero(bad))
            if step % 20 == 0:
                modes = rng.integers(0, 3, core.num)
            obs = core.step(modes).obs
            step += 1


# ---------------------------------------------------------------- agents meet
def _opposite_lane_slots(par, obs):
    lay = observation_layout(par.config)
    return obs[lay["opposite_lane"]].reshape(par.config.observation.vehicles_per_lane, 5)


def test_av_1_sees_av_0_when_near_and_not_when_far():
    for distance, seen in ((50.0, True), (200.0, False)):
        par = duel_env()
        obs, _ = par.reset(options={"scenarios": duel(distance=distance, lead_gap=10.0, oncoming_lead_gap=10.0)})
        veh = par.core.vehicles()  # world frame: av_0, av_1, then the NPCs
        ahead = veh["s"][0, 1] - veh["s"][0, 0]  # av_1 drives towards -s: av_0 is this far ahead of it
        slots = _opposite_lane_slots(par, obs["av_1"])
        xs = slots[slots[:, 0] == 1, 1] * par.config.observation.position_scale
        assert np.any(np.isclose(xs, ahead, atol=1e-3)) == seen, (distance, xs, ahead)


def test_two_avs_overtaking_into_each_other_crash_and_name_each_other():
    par = duel_env()
    par.reset(options={"scenarios": duel()})
    while par.agents:
        _, rew, term, trunc, infos = par.step({a: OVERTAKE for a in par.agents})
    assert term == {"av_0": True, "av_1": True} and trunc == {"av_0": False, "av_1": False}
    assert infos["av_0"]["outcome_name"] == infos["av_1"]["outcome_name"] == "crash"
    assert (infos["av_0"]["crashed_into"], infos["av_1"]["crashed_into"]) == ("av_1", "av_0")
    assert (infos["av_0"]["crash_av"], infos["av_1"]["crash_av"]) == (1, 0)
    assert rew["av_0"] < -5 and rew["av_1"] < -5


def test_npc_agents_follow_the_nearest_av_and_pay_for_the_avs():
    par = duel_env(npc_agents=True)
    obs, _ = par.reset(options={"scenarios": duel(distance=120.0)})
    assert par.agents == ["av_0", "av_1", "npc_0", "npc_1"]  # npc_1: av_1's lead, in lane 1
    # Each lead's nearest AV is the one behind it: ahead of the lead along its travel is negative.
    for npc, gap in (("npc_0", 15.0), ("npc_1", 30.0)):
        assert obs[npc][2] * par.config.observation.position_scale == pytest.approx(-(gap + 4.54), abs=1e-4)
    _, rew, *_ = par.step({"av_0": 0, "av_1": 0, "npc_0": 2, "npc_1": 2})
    assert rew["npc_0"] == rew["npc_1"] == pytest.approx(-(rew["av_0"] + rew["av_1"]))


# ---------------------------------------------------------------- finished agents
def test_an_episode_ends_when_every_av_is_done_and_then_steps_empty():
    # av_0: no lead, goal 10 m ahead: success in ~2 s; av_1 follows its slow lead to the time limit.
    scen = make_scenario(lead=None, oncoming_av=(80.0, 4.0, 10.0, 1.0), goal=10.0, time_limit=6.0)
    par = parallel_env(scenario={"oncoming_av": 1, "oncoming_count": 0, "lead_gap": [0.0, 0.0]})
    par.reset(options={"scenarios": scen})
    ended = {}
    steps = 0
    while par.agents:
        live = list(par.agents)
        obs, rew, term, trunc, infos = par.step({a: 0 for a in live})
        assert set(obs) == set(rew) == set(term) == set(trunc) == set(infos) == set(live)  # only live agents
        ended.update({a: (steps, infos[a]["outcome_name"]) for a in live if term[a] or trunc[a]})
        if "av_0" in ended and "finish" not in ended:
            ended["finish"] = float(par.core.x[0])
        steps += 1
    assert ended["av_0"][1] == "success" and ended["av_1"] == (59, "timeout") and ended["av_0"][0] < 30
    assert par.core.x[0] == ended["finish"]  # av_0 waited, frozen where it finished
    assert par.step({}) == ({}, {}, {}, {}, {})  # what SuperSuit 3.11's black death sends
    with pytest.raises(RuntimeError, match="reset"):
        par.step({"av_0": 0})


# ---------------------------------------------------------------- SuperSuit parameter sharing
def test_supersuit_black_death_vector_of_roads():
    """``k`` roads x E AVs as one Gymnasium vector env: a finished AV gets zeros until its road ends,
    then the whole road restarts."""
    import gymnasium

    par = parallel_env(scenario={"oncoming_av": 1, "oncoming_count": 0, "time_limit": 3.0})
    vec = sb3_vec_env(par, 3, base_class="gymnasium")
    assert isinstance(vec, gymnasium.vector.VectorEnv) and vec.num_envs == 6
    obs, infos = vec.reset(seed=0)
    assert obs.shape == (6, par.core.obs_size) and len(infos) == 6
    first = obs.copy()
    ends = []
    for step in range(70):  # 3 s at dt = 0.1: every road times out on step 30, and again on step 61
        obs, rew, term, trunc, infos = vec.step(np.zeros(6, np.int64))
        assert obs.shape == (6, par.core.obs_size) and rew.shape == (6,)
        if (term | trunc).any():
            assert (term | trunc).all()  # whole roads, and here every road at once
            ends.append(step)
    # SuperSuit 3.11.0 ends a road one step late (the empty step): 30 core steps, then one more.
    assert ends in ([29, 59], [30, 61])
    assert not np.array_equal(obs, first)  # fresh roads: each copy continues its own generator


def test_parameter_sharing_ppo_on_supersuit_vector():
    """A few hundred steps of stable-baselines3's PPO, one shared policy for every AV of two duel roads,
    seeded with PPO(seed=0) (SuperSuit 3.11's own SB3 wrapper raises AttributeError: 'ConcatVecEnv'
    object has no attribute 'seed'; issue 36): sb3_vec_env seeds the next reset, road i with seed + i."""
    import torch
    from stable_baselines3 import PPO

    vec = sb3_vec_env(parallel_env(load_suite("duel")), num_roads=2)
    assert vec.num_envs == 4
    assert vec.seed(7) == [7, 8, 9, 10]
    first = vec.reset()
    vec.seed(7)
    np.testing.assert_array_equal(vec.reset(), first)  # the same seed, the same roads
    vec.seed(8)
    shifted = vec.reset()
    np.testing.assert_array_equal(shifted[:2], first[2:])  # road i is seeded seed + i (rows road by road)
    assert not np.array_equal(shifted, first)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # a 32-unit MLP: more threads only contend with the other tests
    try:
        model = PPO(
            "MlpPolicy",
            vec,
            n_steps=64,
            batch_size=64,
            n_epochs=2,
            device="cpu",
            seed=0,
            policy_kwargs={"net_arch": [32]},
            verbose=0,
        )
        before = [p.detach().clone() for p in model.policy.parameters()]
        model.learn(total_timesteps=512)  # 128 steps of the vector: 2 roads x 2 AVs
    finally:
        torch.set_num_threads(threads)
    assert model.num_timesteps == 512
    after = list(model.policy.parameters())
    assert all(torch.isfinite(p).all() for p in after)
    assert all(not torch.equal(a, b) for a, b in zip(before, after, strict=True))


# ---------------------------------------------------------------- batching on the core
def test_the_core_steps_n_roads_as_e_times_n_rows_like_n_envs():
    """The fast route: one core over N roads; AV e of road n is row e * N + n, bit-identical to
    ``av_e`` of a PettingZoo env on road n."""
    suite = load_suite("platoon")
    roads = suite.scenarios().take(slice(0, 4))
    core = OvertakeCore(suite.config)
    obs = core.reset(roads)
    n, e = 4, roads.num_avs
    assert obs.shape == (e * n, core.obs_size)
    modes = np.random.default_rng(0).integers(0, 3, (25, e * n))
    for m in modes:
        res = core.step(m)
    for road in range(n):
        par = parallel_env(suite, hold_steps=1)  # one core step per env step, as the core is stepped here
        o, _ = par.reset(options={"scenarios": roads.take([road])})
        for m in modes:
            o, r, *_ = par.step({f"av_{k}": int(m[k * n + road]) for k in range(e) if f"av_{k}" in par.agents})
        for k in range(e):
            if f"av_{k}" in o:
                np.testing.assert_array_equal(o[f"av_{k}"], res.obs[k * n + road])
                assert r[f"av_{k}"] == res.reward[k * n + road]


def test_same_seed_same_episodes_over_several_roads():
    """PettingZoo's parallel_seed_test stops after one step (its ``any(terminations)`` tests the dict's
    keys); this runs 300 steps across road resets, NPC agents included."""

    def rollout(seed: int) -> list:
        par = parallel_env(
            load_suite("duel"), npc_agents=True, scenario={**load_suite("duel").config.scenario, "time_limit": 8.0}
        )
        rng = np.random.default_rng(5)
        trace = [par.reset(seed=seed)[0]]
        for _ in range(300):
            if not par.agents:
                trace.append(par.reset()[0])
            obs, rew, *_ = par.step({a: int(rng.integers(par.action_space(a).n)) for a in par.agents})
            trace.append((obs, rew))
        return trace

    def flat(trace) -> list:
        out = []
        for item in trace:
            for d in item if isinstance(item, tuple) else (item,):
                out += [(k, np.asarray(v).tobytes()) for k, v in sorted(d.items())]
        return out

    a, b, c = flat(rollout(3)), flat(rollout(3)), flat(rollout(4))
    assert a == b and a != c and len(a) > 600


def test_aec_api_test_and_render_on_a_duel():
    from pettingzoo.test import api_test

    from overtakezoo.envs import env

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        api_test(env(load_suite("duel")), num_cycles=200)
    assert _unexpected(caught) == []
    par = parallel_env(load_suite("duel"), render_mode="rgb_array")
    par.reset(seed=0)
    par.step({a: OVERTAKE for a in par.agents})
    img = par.render()
    assert img.dtype == np.uint8 and img.ndim == 3 and img.std() > 10
    par.close()
