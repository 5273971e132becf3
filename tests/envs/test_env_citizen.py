"""The env as a good RL citizen: one reward in the env, finite observation bounds, Gymnasium's
vector wrappers, and clear errors on misuse (stepping a finished episode, bad actions)."""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path

import gymnasium
import numpy as np
import pytest
from gymnasium.wrappers import vector as vector_wrappers

from overtakezoo.benchmark.results.results import config_sha256
from overtakezoo.envs import (
    EnvConfig,
    OvertakeCore,
    make_scenario,
    make_vec,
    observation_layout,
    observation_size,
    parallel_env,
)
from overtakezoo.envs.config import RewardConfig
from overtakezoo.envs.faces._compat import AutoresetMode  # gymnasium 1.1+'s own, or its stand-in on 1.0
from overtakezoo.envs.faces.spaces import ego_observation_space, npc_observation_space, npc_start_extent
from overtakezoo.envs.suites import load_suite

ENV_ID = "overtakezoo/Overtake-v0"
HYPERPARAMS = Path(__file__).resolve().parents[2] / "zoo" / "hyperparams"


# ------------------------------------------------------------------ reward
def test_default_reward_ranks_rule_fsm_above_the_constant_baselines():
    from overtakezoo.benchmark.results.returns import mean_returns

    means = mean_returns("table1-train", ("rule-fsm", "always-follow", "always-overtake"), limit=200)
    assert means["rule-fsm"] > means["always-overtake"] > means["always-follow"], means
    # The paper's weights alone (no time cost) rank never overtaking first: the defect this fixes.
    paper = {"progress": 0.1, "crash": -20.0, "timeout": 0.0, "offroad": -20.0, "time": 0.0}
    old = mean_returns("table1-train", ("rule-fsm", "always-follow"), reward=paper, limit=200)
    assert old["always-follow"] > old["rule-fsm"], old


def test_time_cost_is_paid_per_running_step():
    cfg = EnvConfig()
    scen = make_scenario(lead=(15.0, 2.0))
    with_time, without = OvertakeCore(cfg), OvertakeCore(dataclasses.replace(cfg, reward=RewardConfig(time=0.0)))
    with_time.reset(scen)
    without.reset(scen)
    r1, r0 = with_time.step([0]).reward[0], without.step([0]).reward[0]
    assert r1 - r0 == pytest.approx(cfg.reward.time) and cfg.reward.time < 0
    # A finished (frozen) row pays nothing.
    core = OvertakeCore(cfg)
    core.reset(make_scenario(lead=(15.0, 2.0), time_limit=0.2))
    core.step([0])
    assert core.step([0]).truncated[0]
    assert core.step([0]).reward[0] == 0.0


def test_trainers_have_no_reward_of_their_own(tmp_path):
    from overtakezoo.zoo.train.bc import BCHyperparams
    from overtakezoo.zoo.train.contract import load_hyperparams

    for path in HYPERPARAMS.glob("*.toml"):
        hp = tomllib.loads(path.read_text())
        assert "reward" not in hp and "time_penalty" not in hp, path.name
    for extra in ("time_penalty = 0.01\n", "[reward]\nsuccess = 5.0\n"):
        bad = tmp_path / "hp.toml"
        bad.write_text("steps = 10\n" + extra)
        with pytest.raises(ValueError, match="env's reward"):  # the one reader, for every trainer
            load_hyperparams(BCHyperparams, bad)


def test_dqn_trainer_refuses_a_reward_override():
    from overtakezoo.benchmark.suite_groups import load_training
    from overtakezoo.zoo.train.dqn import train
    from overtakezoo.zoo.train.typed import HyperparameterError

    with pytest.raises(HyperparameterError, match="time_penalty"):
        train(load_training("table1-train"), steps=1, overrides={"time_penalty": 0.01}, progress=False)


def test_results_hash_ignores_the_reward():
    cfg = load_suite("table1").config
    other = dataclasses.replace(cfg, reward=RewardConfig(success=99.0))
    assert config_sha256(cfg) == config_sha256(other)
    assert config_sha256(cfg) != config_sha256(dataclasses.replace(cfg, dt=0.05))


# ------------------------------------------------------- observation bounds
@pytest.mark.parametrize("suite", ["table1", "urban-50", "oncoming-8", "dense"])
def test_observations_of_random_play_lie_in_the_box(suite):
    """The core's own (unclipped) observations, 150 scenarios of the suite under random modes
    (a new mode every step in half the rows, every 2 s in the rest), every step to the end."""
    s = load_suite(suite)
    space = ego_observation_space(s.config)
    assert np.isfinite(space.low).all() and np.isfinite(space.high).all()
    core = OvertakeCore(s.config)
    obs = core.reset(s.scenarios().take(slice(0, 150)))
    rng = np.random.default_rng(7)
    modes = rng.integers(0, 3, core.num)
    steps = 0
    while not core.done.all():
        _assert_in(obs, space, f"{suite} step {steps}")
        fresh = rng.integers(0, 3, core.num)
        modes = np.where((np.arange(core.num) % 2 == 0) | (steps % 20 == 0), fresh, modes)
        obs = core.step(modes).obs
        steps += 1
    _assert_in(obs, space, f"{suite} final")


def test_npc_agents_observations_lie_in_their_boxes():
    env = parallel_env(npc_agents=True, scenario={"platoon_size": 2, "oncoming_count": 3, "follower_count": 1})
    rng = np.random.default_rng(3)
    for seed in range(6):
        obs, _ = env.reset(seed=seed)
        while env.agents:
            for agent, o in obs.items():
                _assert_in(o[None], env.observation_space(agent), agent)
            # NPCs mostly accelerate flat out: the fastest they can get.
            actions = {
                a: (int(rng.integers(0, 3)) if a.startswith("av_") else int(rng.choice([2, 3, 3, 3])))
                for a in env.agents
            }
            obs, *_ = env.step(actions)
    dist = env.distribution
    assert np.isfinite(npc_observation_space(env.config, npc_start_extent(dist)).high).all()


def test_a_scenario_outside_the_distribution_is_clipped_into_the_box():
    e = gymnasium.make(ENV_ID)
    fast = make_scenario(lead=(15.0, 2.0), oncoming=[(30.0, 20.0)])  # an oncoming car at 72 km/h
    obs, _ = e.reset(seed=0, options={"scenarios": fast})
    for _ in range(30):
        assert e.observation_space.contains(obs)
        obs, *_ = e.step(0)


def _assert_in(obs, space, where):
    low, high = space.low, space.high
    bad = np.argwhere((obs < low) | (obs > high))
    assert not len(bad), (
        f"{where}: feature {bad[0][1]} = {obs[tuple(bad[0])]} outside [{low[bad[0][1]]}, {high[bad[0][1]]}]"
    )


# ----------------------------------------------------------- vector faces
@pytest.mark.parametrize(
    "wrap",
    [
        vector_wrappers.NormalizeObservation,
        vector_wrappers.FlattenObservation,
        lambda v: vector_wrappers.TransformObservation(v, lambda o: 2.0 * o),
    ],
    ids=["normalize", "flatten", "transform"],
)
def test_make_vec_steps_under_gymnasiums_observation_wrappers(wrap):
    vec = wrap(gymnasium.make_vec(ENV_ID, num_envs=4, scenario={"time_limit": 1.0}))
    obs, _ = vec.reset(seed=0)
    for _ in range(25):  # across two autoresets
        obs, rew, term, trunc, _ = vec.step(vec.action_space.sample())
        assert obs.shape == (4, observation_size(EnvConfig())) and np.isfinite(obs).all()
    vec.close()


def test_make_vec_next_step_autoreset():
    vec = make_vec(num_envs=3, scenario={"time_limit": 1.0})
    assert vec.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    vec.reset(seed=4)
    for _ in range(10):
        obs, rew, term, trunc, infos = vec.step(np.ones(3, np.int64))
    assert trunc.all() and "final_obs" not in infos
    np.testing.assert_allclose(infos["t"], 1.0)  # the ended episodes' info and last observation
    ended = obs
    obs, rew, term, trunc, infos = vec.step(np.full(3, 2, np.int64))  # actions ignored: new episodes
    assert not term.any() and not trunc.any() and (rew == 0.0).all()
    np.testing.assert_array_equal(infos["t"], 0.0)
    assert (
        not np.array_equal(obs, ended) and (obs[:, observation_layout(EnvConfig())["mode"]][:, 0] == 1.0).all()
    )  # mode one-hot: follow
    obs, rew, *_ = vec.step(np.zeros(3, np.int64))
    np.testing.assert_allclose(vec.core.t, 0.1)
    # The same seed draws the same episodes in both modes (one generator, same order of draws).
    a, b = make_vec(num_envs=3, autoreset_mode="SameStep"), make_vec(num_envs=3)
    np.testing.assert_array_equal(a.reset(seed=2)[0], b.reset(seed=2)[0])
    with pytest.raises(ValueError, match="autoreset_mode"):
        make_vec(num_envs=2, autoreset_mode="Disabled")


def test_gymnasium_single_env_normalize_wrapper_refuses_vector_envs():
    # Gymnasium's single-env wrappers take a gymnasium.Env, never a VectorEnv (its own included):
    # vector envs use gymnasium.wrappers.vector.*.
    with pytest.raises((TypeError, AssertionError)) as err:  # AssertionError before 1.2
        gymnasium.wrappers.NormalizeObservation(gymnasium.make_vec(ENV_ID, num_envs=2))
    # gymnasium 1.0's check is a bare `assert isinstance(env, Env)`, without a message
    assert "gymnasium.Env" in str(err.value) or (
        err.type is AssertionError and gymnasium.__version__.startswith("1.0.")
    )


# ------------------------------------------------------------------ misuse
def test_stepping_a_finished_gym_episode_raises():
    e = gymnasium.make(ENV_ID, scenario={"time_limit": 0.3}).unwrapped
    with pytest.raises(RuntimeError, match="reset"):
        e.step(0)
    e.reset(seed=0)
    done = False
    while not done:
        _, _, term, trunc, _ = e.step(0)
        done = term or trunc
    with pytest.raises(RuntimeError, match="call reset"):
        e.step(0)
    e.reset(seed=1)
    e.step(0)  # fine again


@pytest.mark.parametrize("action", [3, -1, 1.5, 1.0, True, "1", None, np.array([1, 2])])
def test_gym_env_refuses_bad_actions(action):
    e = gymnasium.make(ENV_ID).unwrapped
    e.reset(seed=0)
    with pytest.raises(ValueError, match="OvertakeEnv.step: action"):
        e.step(action)
    e.step(np.int64(1))  # numpy integers, and 0-d arrays, are fine
    e.step(np.array(2))


@pytest.mark.parametrize(
    "agent,action",
    [("av_0", -1), ("av_0", 3), ("av_0", 1.5), ("av_1", 2.0), ("npc_0", -1), ("npc_1", 4), ("npc_0", 0.5)],
)
def test_pettingzoo_bad_actions_raise_naming_the_agent(agent, action):
    env = parallel_env(npc_agents=True, scenario={"platoon_size": 2})
    env.reset(seed=0)
    actions = {a: 0 for a in env.agents}
    actions[agent] = action
    with pytest.raises(ValueError, match=rf"^{agent}: action"):
        env.step(actions)
    with pytest.raises(KeyError, match="unknown agent 'av_9'"):
        env.step({**{a: 0 for a in env.agents}, "av_9": 1})
    with pytest.raises(KeyError, match="ego_<i> was renamed av_<i>"):
        env.step({**{a: 0 for a in env.agents}, "ego_0": 1})


def test_vector_env_refuses_bad_actions():
    vec = make_vec(num_envs=3)
    with pytest.raises(RuntimeError, match="reset"):
        vec.step([0, 0, 0])
    vec.reset(seed=0)
    with pytest.raises(ValueError, match=r"actions\[1\]: action -1"):
        vec.step([0, -1, 0])
    with pytest.raises(ValueError, match=r"^actions\[1\]: action 1.5 is not an integer in 0\.\.2$"):
        vec.step(np.array([0.0, 1.5, 0.0]))
    with pytest.raises(
        ValueError, match=r"^actions\[0\]: action 0.0 is not an integer"
    ):  # floats: refused, as gym's 1.0
        vec.step(np.array([0.0, 1.0, 0.0]))
    with pytest.raises(ValueError, match="dtype bool"):
        vec.step(np.array([True, False, True]))
    with pytest.raises(ValueError, match="shape"):
        vec.step([0, 1])


def _face_step(face: str, action):
    """One step of ``face`` (3 envs or agents' worth where it is batched) with ``action`` in the
    middle; returns the name the face's error message starts with."""
    if face == "gym":
        e = gymnasium.make(ENV_ID).unwrapped
        e.reset(seed=0)
        e.step(action)
    elif face == "vector":
        vec = make_vec(num_envs=3)
        vec.reset(seed=0)
        vec.step(np.array([0, action, 0]))  # a float among ints makes the batch float: refused per entry
    elif face == "pettingzoo":
        env = parallel_env(scenario={"platoon_size": 2})
        env.reset(seed=0)
        env.step({"av_0": 0, "av_1": action})
    else:
        torch = pytest.importorskip("torch")
        pytest.importorskip("rsl_rl")
        from overtakezoo.envs.faces.rsl_rl import OvertakeRslRlEnv

        env = OvertakeRslRlEnv(3, EnvConfig(), seed=0)
        env.step(torch.tensor([[0.0], [1.0], [2.0]]))  # rsl-rl's float column: whole numbers are modes
        env.step(torch.tensor([[0.0], [action], [0.0]]))


FACE_WHO = {"gym": r"OvertakeEnv\.step", "vector": r"actions\[1\]", "pettingzoo": "av_1", "rsl_rl": r"actions\[1\]"}


@pytest.mark.parametrize(
    "action,shown",
    [(5, r"5(\.0)?"), (-1, r"-1(\.0)?"), (1.7, r"1\.7"), (float("nan"), "nan")],
    ids=["5", "-1", "1.7", "nan"],
)
@pytest.mark.parametrize("face", list(FACE_WHO))
def test_every_face_refuses_a_bad_action_with_one_message(face, action, shown):
    # The same one-line ValueError from every face: never rounded, clamped or wrapped into a mode.
    with pytest.raises(ValueError, match=rf"^{FACE_WHO[face]}: action {shown} is not an integer in 0\.\.2$"):
        _face_step(face, action)
