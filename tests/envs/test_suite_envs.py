"""Suites are environments: every built-in suite is a registered id whose env steps exactly what the
suite evaluates (its settings, its distribution, the zoo's 1 s decision hold), through the single
Gymnasium env, the vector env and PettingZoo."""

from __future__ import annotations

import shutil
import warnings

import gymnasium
import numpy as np
import pettingzoo
import pytest
from gymnasium.utils.env_checker import check_env

import overtakezoo.envs  # noqa: F401  (registers the ids)
from overtakezoo import zoo
from overtakezoo.benchmark.run.runner import run_indices
from overtakezoo.benchmark.suite_groups import DRIVERS, MULTI
from overtakezoo.envs import ConfigError, OvertakeEnv, OvertakeVectorEnv, make_vec, parallel_env
from overtakezoo.envs.faces._compat import AutoresetMode  # gymnasium 1.1+'s own, or its stand-in on 1.0
from overtakezoo.envs.faces.gym import ENV_ID, ENV_ID_V0
from overtakezoo.envs.suites import SuiteError, load_suite, suite_env_ids, suite_names

with warnings.catch_warnings():
    warnings.simplefilter("ignore", DeprecationWarning)
    from pettingzoo.test import parallel_api_test


def _episode(env, decider, scenarios):
    """One episode of ``decider`` through the single env on ``scenarios`` (one row): the last info."""
    obs, info = env.reset(options={"scenarios": scenarios})
    decider.reset()
    done = False
    while not done:
        obs, _, terminated, truncated, info = env.step(decider.act(obs))
        done = terminated or truncated
    return info


# ----------------------------------------------------------------- the ids
def test_every_builtin_suite_is_a_registered_id_with_the_zoo_hold():
    ids = suite_env_ids()
    assert sorted(i.name for i in ids.values()) == suite_names()
    for env_id, entry in ids.items():
        suite = load_suite(entry.name)
        assert env_id == f"overtakezoo/{suite.name}-v{suite.version}"
        assert entry.hold_steps == round(1.0 / suite.config.dt) == 10  # the zoo's 1 s decision
        assert pettingzoo.parallel_registry[env_id].kwargs == {"suite": entry.name, "hold_steps": 10}
        multi = suite.num_avs > 1
        assert entry.multi_av == multi and env_id in gymnasium.registry
        assert gymnasium.spec(env_id).kwargs == {"suite": entry.name, "hold_steps": 10}
        # A multi-AV suite's Gymnasium id only refuses, showing the PettingZoo call (issue 36).
        refuses = gymnasium.spec(env_id).entry_point == "overtakezoo.envs.faces.pettingzoo:gymnasium_refusal"
        assert refuses == multi
    assert "overtakezoo/table1-train-v2" in gymnasium.registry
    mixed_drivers = {f"mixed-drivers-{p}" for p in DRIVERS}  # (held-out drivers on mixed-traffic's roads)
    assert {entry.name for entry in ids.values() if entry.multi_av} == {
        *MULTI,
        *(f"{m}-train" for m in MULTI),
    } | mixed_drivers


def test_a_suite_id_is_the_suites_world_and_overtake_v0_is_unchanged():
    made = gymnasium.make("overtakezoo/table1-v2")
    env = made.unwrapped
    assert isinstance(env, OvertakeEnv) and env.hold_steps == 10
    assert env.config == load_suite("table1").config  # scripted NPCs, no prediction: the suite's settings
    assert env.distribution == load_suite("table1").distribution
    with pytest.warns(DeprecationWarning, match=r"Overtake-v0 is out of date.*upgrading to version `v1`"):
        default = gymnasium.make("overtakezoo/Overtake-v0").unwrapped
    assert default.hold_steps == 1 and default.config == overtakezoo.envs.EnvConfig()
    made.close()


def test_overtake_v1_is_table1_train_v2_with_the_zoo_hold():
    # Issue 36: the id the submit guide trains on is the training world at the zoo's 1 s decision, the
    # kwargs of table1-train v2's id. A new table1-train version must come with a new Overtake version.
    assert ENV_ID == "overtakezoo/Overtake-v1" and ENV_ID_V0 == "overtakezoo/Overtake-v0"
    assert (
        gymnasium.spec(ENV_ID).kwargs
        == gymnasium.spec("overtakezoo/table1-train-v2").kwargs
        == {"suite": "table1-train", "hold_steps": 10}
    )
    assert pettingzoo.parallel_registry[ENV_ID].kwargs == gymnasium.spec(ENV_ID).kwargs
    env = gymnasium.make(ENV_ID).unwrapped
    train = load_suite("table1-train")
    assert env.hold_steps == 10 and env.config == train.config and env.distribution == train.distribution
    assert gymnasium.make_vec(ENV_ID, num_envs=2).hold_steps == 10
    assert gymnasium.spec("overtakezoo/Overtake-v0").kwargs == {}


def test_make_make_vec_and_parallel_env_take_a_suite_name_or_file(tmp_path):
    path = tmp_path / "mine.toml"
    shutil.copy(load_suite("table1-train").path.with_name("table1.toml"), path)
    table1 = load_suite("table1").config
    for suite in ("table1-train", str(path)):
        assert gymnasium.make("overtakezoo/Overtake-v0", suite=suite).unwrapped.config == table1
        vec = gymnasium.make_vec("overtakezoo/Overtake-v0", num_envs=2, suite=suite)
        # made from a suite: the suite's hold, the zoo's 1 s, as its id (issue 36)
        assert isinstance(vec, OvertakeVectorEnv) and vec.config == table1 and vec.hold_steps == 10
        assert parallel_env(suite=suite).config == table1
    held = gymnasium.make_vec("overtakezoo/table1-v2", num_envs=3)
    assert held.hold_steps == 10 and held.config == table1
    # keyword arguments still override EnvConfig keys, and the hold
    env = gymnasium.make("overtakezoo/table1-v2", hold_steps=1, render_mode="rgb_array").unwrapped
    assert env.hold_steps == 1 and env.render_mode == "rgb_array"
    duel = pettingzoo.make("parallel", "overtakezoo/duel-v1")
    assert duel.hold_steps == 10 and duel.possible_agents == ["av_0", "av_1"]


def test_bad_suites_and_holds_are_one_line_errors():
    with pytest.raises(SuiteError, match=r"unknown suite 'tabel1' \(known: adversarial, .*table1"):
        gymnasium.make("overtakezoo/Overtake-v0", suite="tabel1")
    with pytest.raises(ConfigError, match="use parallel_env"):
        gymnasium.make("overtakezoo/Overtake-v0", suite="duel")
    for bad in (0, -1, 2.5, True, "10"):
        with pytest.raises(ConfigError, match="hold_steps: expected a positive integer"):
            OvertakeEnv(hold_steps=bad)
    with pytest.raises(ConfigError, match="hold_steps: 7 is not a multiple of decision_interval 5"):
        make_vec(num_envs=2, decision_interval=5, hold_steps=7)


# ------------------------------------------------ the env is what the suite evaluates
@pytest.mark.parametrize("name", ["always-overtake", "rule-fsm"])
def test_the_suite_env_gives_the_runners_outcomes(name):
    """A zoo member acting through gymnasium.make("overtakezoo/table1-v2") (each decision held 10
    steps) ends every scenario exactly as the benchmark runner does with the same hold."""
    suite = load_suite("table1")
    indices = np.arange(0, suite.count, 150)
    decider = zoo.load(name, suite.config)
    decider.action_repeat = 10  # the runner holds each decision hold_steps(1, 10) = 10 core steps
    ref = run_indices(suite, decider, indices, safety=False)
    env = gymnasium.make("overtakezoo/table1-v2")
    scenarios = suite.scenarios().take(indices)
    infos = [_episode(env, decider, scenarios.take([k])) for k in range(len(indices))]
    np.testing.assert_array_equal([i["outcome"] for i in infos], ref["outcome"])
    np.testing.assert_array_equal([i["crash_npc"] for i in infos], ref["crash_npc"])
    np.testing.assert_array_equal([round(i["t"], 3) for i in infos], ref["episode_time"])
    assert len(set(ref["outcome"].tolist())) > 1  # successes and crashes both occur


def test_check_env_and_parallel_api_test_pass_on_suite_envs():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(gymnasium.make("overtakezoo/table1-train-v2").unwrapped)
        check_env(gymnasium.make("overtakezoo/dense-v1").unwrapped)
    assert not [w for w in caught if "overtakezoo" in str(w.filename) or "env_checker" in str(w.filename)], [
        str(w.message) for w in caught
    ]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        parallel_api_test(pettingzoo.make("parallel", "overtakezoo/duel-v1"), num_cycles=200)
        parallel_api_test(parallel_env("platoon", hold_steps=10), num_cycles=200)


# ------------------------------------------------------------- the vector env holds per row
@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
def test_vector_env_holds_per_row_as_the_single_env(mode):
    """Each row of make_vec("overtakezoo/table1-v2") steps its first episode exactly as the single env
    with the same hold: the same rewards at every env step, ended at the same env step with the same
    last observation and outcome. Then Gymnasium's autoreset: next step, the following step ignores
    the row's action (reward 0, not done, the new episode's first observation); same step, the step
    that ends it returns final_obs / final_info and the new episode's observation."""
    suite = load_suite("table1")
    n = 6
    scenarios = suite.scenarios().take(np.arange(n) * 37)
    single = gymnasium.make("overtakezoo/table1-v2").unwrapped
    decider = zoo.load("rule-fsm", suite.config)
    ref = []
    for k in range(n):
        obs, _ = single.reset(options={"scenarios": scenarios.take([k])})
        decider.reset()
        rows, done = [], False
        while not done:
            obs, reward, term, trunc, info = single.step(decider.act(obs))
            rows.append((reward, term, trunc, obs, info["outcome"]))
            done = term or trunc
        ref.append(rows)

    vec = gymnasium.make_vec("overtakezoo/table1-v2", num_envs=n, autoreset_mode=mode)
    assert vec.hold_steps == 10
    obs, _ = vec.reset(seed=0, options={"scenarios": scenarios})
    decider.reset()
    at = np.zeros(n, int)  # env steps of each row's first episode seen so far
    ended = np.zeros(n, bool)
    restarted = np.zeros(n, bool)
    while not restarted.all():
        pending = ended & ~restarted  # NEXT_STEP: ended at the previous step, restart now
        obs, reward, term, trunc, infos = vec.step(decider.act(obs))
        for k in np.flatnonzero(pending):
            assert reward[k] == 0 and not term[k] and not trunc[k] and infos["t"][k] == 0.0
            restarted[k] = True
        for k in np.flatnonzero(~ended):
            r, t, tr, last, outcome = ref[k][at[k]]
            assert (reward[k], term[k], trunc[k]) == (r, t, tr), (k, at[k])
            at[k] += 1
            if not (t or tr):
                np.testing.assert_array_equal(obs[k], last)
                continue
            ended[k] = True
            assert at[k] == len(ref[k])  # reported at the env step whose hold ended it
            if mode == AutoresetMode.SAME_STEP:
                assert infos["_final_obs"][k] and infos["final_info"]["outcome"][k] == outcome
                np.testing.assert_array_equal(infos["final_obs"][k], last)
                assert infos["t"][k] == 0.0  # the new episode, started in this step
                restarted[k] = True
            else:
                np.testing.assert_array_equal(obs[k], last)
        decider.reset(term | trunc)
    assert len({len(r) for r in ref}) > 1  # rows ended at different env steps
    vec.close()


def test_vector_env_holds_the_decision_interval_by_default():
    vec = make_vec(num_envs=2, decision_interval=5, scenario={"time_limit": 2.0})
    assert vec.hold_steps == 5
    vec.reset(seed=0)
    assert [bool(vec.step([0, 1])[3].all()) for _ in range(4)] == [False, False, False, True]
    np.testing.assert_allclose(vec.core.t, 2.0)
