"""The env faces (PettingZoo parallel / AEC, Gymnasium env / vector env, rendering) over the core."""

from __future__ import annotations

import warnings

import gymnasium
import matplotlib
import numpy as np
import pettingzoo
import pytest
from gymnasium.utils.env_checker import check_env

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

with warnings.catch_warnings():  # pettingzoo.test imports its own example envs through a deprecated path
    warnings.simplefilter("ignore", DeprecationWarning)
    from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test, seed_test

from overtakezoo.envs import (  # noqa: E402
    ConfigError,
    OvertakeEnv,
    OvertakeVectorEnv,
    ScenarioDistribution,
    draw_frame,
    env,
    frame_from_core,
    make_scenario,
    make_vec,
    parallel_env,
    register_envs,
)
from overtakezoo.envs.faces._compat import AutoresetMode  # noqa: E402  (gymnasium 1.1+'s own, or its stand-in on 1.0)
from overtakezoo.envs.faces.pettingzoo import NPC_ACCELERATIONS, NPC_OBS_SIZE  # noqa: E402

ENV_ID = "overtakezoo/Overtake-v0"
# Observation bounds are finite (envs/faces/spaces.py): no checker warning is accepted, but (with NPC
# agents) the one about the two observation sizes.
INF_WARNINGS = ()
NPC_WARNINGS = INF_WARNINGS + ("different shapes", "different observation space sizes")


def _unexpected(caught, allowed) -> list[str]:
    return [str(w.message) for w in caught if not any(a in str(w.message) for a in allowed)]


# ------------------------------------------------------------------ PettingZoo
def test_parallel_api_test_default():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        parallel_api_test(parallel_env(), num_cycles=1000)
    assert _unexpected(caught, INF_WARNINGS) == []


def test_parallel_api_test_avs_and_npc_agents():
    par = parallel_env(
        npc_agents=True, scenario={"platoon_size": 3, "oncoming_count": 2, "follower_count": 1, "time_limit": 20.0}
    )
    assert par.possible_agents == ["av_0", "av_1", "av_2", "npc_0", "npc_1", "npc_2", "npc_3"]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        parallel_api_test(par, num_cycles=1000)
    assert _unexpected(caught, NPC_WARNINGS) == []


@pytest.mark.parametrize("kwargs", [{}, {"npc_agents": True, "scenario": {"platoon_size": 2}}])
def test_parallel_seed_test(kwargs):
    parallel_seed_test(lambda: parallel_env(**kwargs))


@pytest.mark.parametrize("kwargs", [{}, {"npc_agents": True, "scenario": {"platoon_size": 2, "time_limit": 15.0}}])
def test_aec_api_test(kwargs):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        api_test(env(**kwargs), num_cycles=300)
    assert _unexpected(caught, NPC_WARNINGS) == []


def test_aec_seed_test():
    seed_test(lambda: env(npc_agents=True, scenario={"platoon_size": 2}), num_cycles=100)


def _rollout(par, seed: int, steps: int) -> list:
    """``steps`` steps with seeded random actions (resetting when every agent is done)."""
    rng = np.random.default_rng(123)
    trace = []
    obs, _ = par.reset(seed=seed)
    trace.append(obs)
    for _ in range(steps):
        if not par.agents:
            obs, _ = par.reset()
            trace.append(obs)
        actions = {a: int(rng.integers(par.action_space(a).n)) for a in par.agents}
        obs, rew, term, trunc, _ = par.step(actions)
        trace.append((obs, rew, term, trunc))
    return trace


def _same(a, b) -> bool:
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, tuple):
        return all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, np.ndarray):
        return a.dtype == b.dtype and np.array_equal(a, b)
    return a == b


def test_same_seed_bit_identical_over_200_steps():
    cfg = {"npc_agents": True, "scenario": {"platoon_size": 2, "time_limit": 8.0}}  # crosses resets too
    a = _rollout(parallel_env(**cfg), seed=5, steps=200)
    b = _rollout(parallel_env(**cfg), seed=5, steps=200)
    assert len(a) == len(b) > 200
    assert all(_same(x, y) for x, y in zip(a, b, strict=True))
    c = _rollout(parallel_env(**cfg), seed=6, steps=20)
    assert not _same(a[0], c[0])


def test_config_errors_name_the_key():
    with pytest.raises(ConfigError, match="bogus"):
        parallel_env(bogus=1)
    with pytest.raises(ConfigError, match="scenario.lead_gapp"):
        parallel_env(scenario={"lead_gapp": [1, 2]})
    with pytest.raises(ConfigError, match="num_egos"):
        parallel_env(num_egos=0)
    with pytest.raises(ConfigError, match=r"num_egos: 2 is no longer supported .* scenario.platoon_size"):
        parallel_env(num_egos=2)
    with pytest.raises(ConfigError, match="bogus"):
        gymnasium.make(ENV_ID, bogus=1)
    with pytest.raises(ConfigError, match="bogus"):
        make_vec(num_envs=2, bogus=1)
    with pytest.raises(ConfigError, match="num_egos"):
        OvertakeEnv(num_egos=2)
    with pytest.raises(ConfigError, match="scenario: OvertakeEnv drives one automated vehicle"):
        OvertakeEnv(scenario={"platoon_size": 2})
    with pytest.raises(ConfigError, match="scenario: OvertakeVectorEnv"):
        make_vec(num_envs=2, scenario={"oncoming_av": 1, "oncoming_count": 0})
    with pytest.raises(ConfigError, match="npc_agents"):
        make_vec(num_envs=2, npc_agents=True)


def test_the_road_is_drawn_from_the_seed_and_its_avs_are_the_agents():
    par = parallel_env(scenario={"platoon_size": 4})
    obs, infos = par.reset(seed=7)
    expected = ScenarioDistribution.from_dict({"platoon_size": 4}).sample(1, 7)
    for name, value in expected.to_arrays().items():
        np.testing.assert_array_equal(getattr(par.core.scen, name), value)
    assert par.core.num_roads == 1 and par.core.num == 4
    assert set(obs) == set(infos) == {"av_0", "av_1", "av_2", "av_3"}
    space = par.observation_space("av_0")
    assert space is par.observation_space("av_3") and space.shape == (par.core.obs_size,)
    assert all(space.contains(o) for o in obs.values())
    assert par.action_space("av_0") is par.action_space("av_0") and par.action_space("av_0").n == 3


def test_finished_av_leaves_agents_while_others_run():
    # av_0 has no lead and its goal 10 m ahead: it succeeds in ~2 s; av_1 follows its slow lead.
    scen = make_scenario(lead=None, oncoming_av=(80.0, 4.0, 10.0, 1.0), goal=10.0, time_limit=6.0)
    par = parallel_env(scenario={"oncoming_av": 1, "oncoming_count": 0, "lead_gap": [0.0, 0.0]})
    par.reset(options={"scenarios": scen})
    while par.agents == ["av_0", "av_1"]:
        _, _, term, trunc, infos = par.step({a: 0 for a in par.agents})
    assert term == {"av_0": True, "av_1": False} and infos["av_0"]["outcome_name"] == "success"
    assert par.agents == ["av_1"]
    obs, *_ = par.step({"av_1": 0})  # the finished AV needs no action
    assert set(obs) == {"av_1"}
    with pytest.raises(KeyError, match="av_1"):
        par.step({})
    while par.agents:
        _, _, _, trunc, infos = par.step({"av_1": 0})
    assert trunc == {"av_1": True} and infos["av_1"]["outcome_name"] == "timeout"


def test_npc_agents_control_npc_acceleration():
    scen = make_scenario(lead=(15.0, 2.0), oncoming=[(80.0, 2.0)])
    runs = {}
    for action in (None, 0):  # IDM, then the strongest braking choice for the lead
        par = parallel_env(npc_agents=True)
        obs, _ = par.reset(options={"scenarios": scen})
        assert par.agents == ["av_0", "npc_0", "npc_1"]
        assert obs["npc_0"].shape == (NPC_OBS_SIZE,) and par.observation_space("npc_0").contains(obs["npc_0"])
        for _ in range(5):
            actions = {"av_0": 0, "npc_1": 2}
            if action is not None:
                actions["npc_0"] = action
            obs, rew, *_ = par.step(actions)
        assert rew["npc_0"] == rew["npc_1"] == -rew["av_0"]
        runs[action] = float(par.core.npc_v[0, 0])
    assert runs[0] == pytest.approx(0.0, abs=1e-9)  # 2 m/s - 5 steps x 0.4 m/s
    assert runs[None] > 1.5
    assert NPC_ACCELERATIONS[0] < 0


def test_decision_interval_repeats_the_action():
    from overtakezoo.envs import OvertakeCore

    scen = make_scenario(lead=(10.0, 2.0), oncoming=[(70.0, 2.0)])
    par = parallel_env(decision_interval=5)
    par.reset(options={"scenarios": scen})
    core = OvertakeCore(par.config)
    core.reset(scen)
    for _ in range(3):
        obs, rew, *_ = par.step({"av_0": 1})
        rewards = [core.step(np.ones(1, np.int64)).reward[0] for _ in range(5)]
        assert rew["av_0"] == pytest.approx(sum(rewards), abs=1e-12)
    np.testing.assert_array_equal(obs["av_0"], core.observe()[0])
    assert par.core.t[0] == pytest.approx(1.5)
    e = OvertakeEnv(decision_interval=5, scenario={"time_limit": 2.0})
    e.reset(seed=0)
    assert [e.step(0)[3] for _ in range(4)] == [False, False, False, True]
    vec = make_vec(num_envs=2, decision_interval=5, scenario={"time_limit": 2.0})  # the vector env holds too
    vec.reset(seed=0)
    assert [bool(vec.step([0, 0])[3].all()) for _ in range(4)] == [False, False, False, True]


def test_pettingzoo_registry():
    par = pettingzoo.make("parallel", ENV_ID, scenario={"platoon_size": 2})
    assert isinstance(par, pettingzoo.ParallelEnv) and par.possible_agents == ["av_0", "av_1"]
    aec = pettingzoo.make("aec", ENV_ID)
    assert isinstance(aec, pettingzoo.AECEnv)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        register_envs()  # idempotent: no "overriding" warnings


# ------------------------------------------------------------------ Gymnasium
@pytest.mark.parametrize("render_mode", [None, "rgb_array"])
def test_gymnasium_check_env(render_mode):
    made = gymnasium.make(ENV_ID, render_mode=render_mode)
    assert isinstance(made.unwrapped, OvertakeEnv)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(made.unwrapped)
    assert _unexpected(caught, INF_WARNINGS) == []
    made.close()


def test_gymnasium_env_reset_seed_and_episode():
    e = gymnasium.make(ENV_ID, scenario={"time_limit": 2.0})
    o1, _ = e.reset(seed=3)
    o2, _ = e.reset(seed=3)
    np.testing.assert_array_equal(o1, o2)
    done, steps = False, 0
    while not done:
        obs, reward, terminated, truncated, info = e.step(0)
        done, steps = terminated or truncated, steps + 1
    assert truncated and steps == 20 and info["outcome_name"] == "timeout"
    assert isinstance(reward, float) and obs.dtype == np.float32


def test_gymnasium_plugin_entry_point_resolves():
    from importlib.metadata import entry_points

    (ep,) = [ep for ep in entry_points(group="gymnasium.envs") if ep.name == "overtakezoo"]
    assert ep.load() is register_envs


# ---------------------------------------------------------------- vector env
def test_make_vec_steps_and_autoresets_in_the_same_step():
    vec = make_vec(num_envs=6, scenario={"time_limit": 1.0}, autoreset_mode=AutoresetMode.SAME_STEP)
    assert vec.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    assert vec.single_action_space.n == 3 and vec.action_space.shape == (6,)
    assert vec.observation_space.shape == (6, vec.single_observation_space.shape[0])
    obs, infos = vec.reset(seed=0)
    assert obs.shape == vec.observation_space.shape and infos["_t"].all()
    for step in range(10):
        obs, rew, term, trunc, infos = vec.step(vec.action_space.sample())
        assert obs.shape == (6, vec.single_observation_space.shape[0]) and rew.shape == (6,)
        if step < 9:
            assert "final_obs" not in infos
    assert trunc.all()  # 1 s at dt = 0.1: every row timed out on the 10th step ...
    assert infos["_final_obs"].all() and infos["_final_info"].all()
    final = np.stack(list(infos["final_obs"]))
    assert final.shape == obs.shape and not np.array_equal(final, obs)  # ... and was replaced
    np.testing.assert_array_equal(infos["final_info"]["outcome"], 3)
    np.testing.assert_array_equal(infos["t"], 0.0)  # the new episodes
    obs, *_ = vec.step(np.zeros(6, np.int64))
    assert vec.observation_space.contains(obs)
    vec.close()


def test_make_vec_partial_reset_and_seeding():
    vec = make_vec(num_envs=4, scenario={"time_limit": 0.5}, autoreset_mode="SameStep")
    vec.reset(seed=1)
    vec.core.t[:2] = -10.0  # rows 0 and 1 get 1 s more: rows 2 and 3 finish first
    for _ in range(5):
        _, _, _, trunc, infos = vec.step([0, 0, 0, 0])
    assert trunc.tolist() == [False, False, True, True]
    assert infos["final_obs"][0] is None and infos["final_obs"][2] is not None
    assert infos["_final_info"].tolist() == [False, False, True, True]
    a, b = make_vec(num_envs=4), make_vec(num_envs=4)
    np.testing.assert_array_equal(a.reset(seed=9)[0], b.reset(seed=9)[0])


def test_gymnasium_make_vec_uses_native_vector_env():
    vec = gymnasium.make_vec(ENV_ID, num_envs=3)
    assert isinstance(vec, OvertakeVectorEnv) and vec.num_envs == 3
    vec.reset(seed=0)
    vec.step(np.ones(3, np.int64))


# ------------------------------------------------------------------ rendering
def test_rgb_array_render_and_no_figure_leak(tmp_path):
    before = plt.get_fignums()
    par = parallel_env(render_mode="rgb_array")
    par.reset(options={"scenarios": make_scenario(lead=(10.0, 2.0), oncoming=[(60.0, 2.0)])})
    for _ in range(30):
        par.step({"av_0": 1})
    img = par.render()
    assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3 and img.shape[0] > 100
    assert img.std() > 10 and len(np.unique(img.reshape(-1, 3), axis=0)) > 20  # not blank
    assert par.render().shape == img.shape  # the figure is reused
    plt.imsave(tmp_path / "frame.png", img)
    par.close()
    assert plt.get_fignums() == before

    e = OvertakeEnv(render_mode="rgb_array")
    e.reset(seed=0)
    assert e.render().shape == img.shape
    e.close()


def test_draw_frame_from_plain_values():
    par = parallel_env()
    par.reset(seed=2)
    par.step({"av_0": 1})
    frame = frame_from_core(par.core, 0)
    for value in frame.values():  # plain values only, so recorded frames can be replayed
        assert isinstance(value, (int, float, np.ndarray))
    fig = matplotlib.figure.Figure()
    ax = fig.add_subplot()
    draw_frame(ax, frame)
    assert "OVERTAKE" in ax.get_title(loc="left")
    assert len(ax.patches) >= 1 + 1 + int(frame["npc_present"].sum())  # road, ego, NPCs
    assert len(ax.lines) == len(frame["plan_offsets"])  # one line per rollout


def test_human_render_headless():
    before = plt.get_fignums()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        e = OvertakeEnv(render_mode="human")
        e.reset(seed=0)
        assert e.step(0)[0] is not None and e.render() is None
        e.close()
    assert plt.get_fignums() == before
