"""The decider protocol (act on (D,) and (N, D), reset(mask)), its conformance checker, and the one
action hold (envs/hold.py) that the runner, the faces and the trainers share."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import LEARNED, needs_shipped_weights
from overtakezoo import zoo
from overtakezoo.benchmark.run.runner import run_suite
from overtakezoo.envs import EnvConfig, OvertakeCore, ScenarioDistribution, observation_size
from overtakezoo.envs.hold import hold, hold_steps
from overtakezoo.envs.suites import load_suite
from overtakezoo.zoo.testing import check_decider

MEMBERS = sorted(zoo.names())  # the registry itself: a new member is checked here without touching this file


def member(name, learned_dir):
    """A zoo member; the learned ones with random weights in the shipped format (the protocol does
    not depend on what the weights learned)."""
    return zoo.load(name, directory=learned_dir) if name in LEARNED else zoo.load(name)


@pytest.mark.parametrize("name", MEMBERS)
def test_one_observation_gives_an_int(name, learned_dir):
    dec = member(name, learned_dir)
    core = OvertakeCore(EnvConfig())
    obs = core.reset(ScenarioDistribution().sample(1, 5))
    if dec.privileged:  # the oracle reads the simulator: bind it to a one-row core
        dec.bind(core)
    mode = dec.act(obs[0])
    assert type(mode) is int and mode in (0, 1, 2), (name, mode)


@pytest.mark.parametrize("name", MEMBERS)
def test_every_member_passes_the_conformance_check(name, learned_dir):
    check_decider(member(name, learned_dir), num=4, decisions=8)


@needs_shipped_weights
@pytest.mark.parametrize("name", LEARNED)
def test_shipped_learned_members_pass_the_conformance_check(name):
    check_decider(zoo.load(name), num=4, decisions=8)


class _BatchOnly:
    """A decider written without the zoo's base class: batch form only, like the old always-*."""

    name, version = "batch-only", "1"

    def reset(self, mask=None):
        pass

    def act(self, obs):
        return np.full(np.shape(obs)[0], 1, np.int64)


def test_checker_names_what_is_wrong():
    with pytest.raises(AssertionError, match=r"one observation of shape \(\d+,\) must return a Python int"):
        check_decider(_BatchOnly())

    class Random(zoo.Decider):
        name = "random"

        def __init__(self):
            super().__init__()
            self.rng = np.random.default_rng(0)

        def act_batch(self, obs):
            return self.rng.integers(0, 3, len(obs))

    with pytest.raises(AssertionError, match="not deterministic"):
        check_decider(Random())

    class Four(zoo.Decider):
        name = "four"

        def act_batch(self, obs):
            return np.full(len(obs), 4)

    with pytest.raises(AssertionError, match=r"returned mode \[4\]"):
        check_decider(Four())

    class NoRepeat(zoo.Decider):
        name, action_repeat = "zero", 0

        def act_batch(self, obs):
            return np.zeros(len(obs), np.int64)

    with pytest.raises(AssertionError, match="action_repeat must be an int >= 1"):
        check_decider(NoRepeat())


def test_a_subclass_that_writes_act_in_batch_form_gets_the_single_form():
    class Old(zoo.Decider):
        name = "old"

        def act(self, obs):
            return np.full(obs.shape[0], 1, np.int64)

    dec = Old()
    obs = np.zeros((5, observation_size(dec.config)), np.float32)
    assert dec.act(obs[0]) == 1 and type(dec.act(obs[0])) is int
    assert dec.act(obs).shape == (5,)
    check_decider(dec)
    with pytest.raises(ValueError, match=r"got shape \(2, 5, \d+\)"):
        dec.act(np.stack([obs, obs]))


def test_hold_steps_rounds_to_the_decision_interval():
    assert hold_steps(1, 10) == 10 and hold_steps(4, 10) == 8 and hold_steps(5, 1) == 5 and hold_steps(1) == 1
    with pytest.raises(ValueError):
        hold_steps(0, 1)


def test_hold_on_a_held_core_equals_stepping_it():
    scen = ScenarioDistribution().sample(6, 3)
    a, b = OvertakeCore(EnvConfig()), OvertakeCore(EnvConfig())
    a.reset(scen), b.reset(scen)
    modes = np.array([1, 1, 0, 1, 0, 1])
    seen = []
    res = hold(a, modes, 25, on_step=lambda m, r: seen.append(m))
    total = np.zeros(6)
    for _ in range(25):
        total += b.step(modes).reward
    assert res.steps == len(seen) == 25
    np.testing.assert_array_equal(res.obs, b.observe())
    np.testing.assert_allclose(res.reward, total, rtol=0, atol=1e-12)


def test_hold_on_an_auto_reset_core_keeps_each_episode_to_itself():
    pool = ScenarioDistribution().sample(16, 4)
    core = OvertakeCore(EnvConfig(), auto_reset=True, source=lambda n, rng: pool.take(rng.integers(0, 16, n)), seed=0)
    core.reset(pool.take(np.arange(8)))
    res = None
    for _ in range(60):  # overtake blindly until some episodes end mid-hold
        res = hold(core, np.ones(8, np.int64), 10)
        if res.finished.any():
            break
    assert res.finished.any() and res.final_obs is not None
    rows = np.flatnonzero(res.finished)
    assert (res.final_info["outcome"][rows] > 0).all()  # the ended episode's outcome, not the new one's
    assert (res.live_steps[rows] <= 10).all() and (res.live_steps[~res.finished] == 10).all()
    assert (res.terminated | res.truncated)[rows].all()


def test_runner_asks_for_a_decision_once_per_hold():
    suite = load_suite("table1")

    class Counting(zoo.Decider):
        name, action_repeat = "counting", 7

        def __init__(self, config):
            super().__init__(config)
            self.calls = 0

        def act_batch(self, obs):
            self.calls += 1
            return np.zeros(len(obs), np.int64)

    dec = Counting(suite.config)
    res = run_suite(suite, dec, limit=4, progress=False)
    assert dec.calls == -(-res.timing["steps"] // 7)  # ceil: the last hold may end early


# Issue 18: all-NaN / all-inf observations made the learned members overtake, rule-fsm and fuzzy
# acted on observations of the wrong width, and every member but the constants raised on (0, D).
def _bound(name, learned_dir, rows):
    """A member and a core of ``rows`` rows (the oracle bound to it), with the core's observations."""
    dec = member(name, learned_dir)
    core = OvertakeCore(EnvConfig())
    obs = core.reset(ScenarioDistribution().sample(rows, 7))
    if dec.privileged:
        dec.bind(core)
    return dec, obs


@pytest.mark.parametrize("name", MEMBERS)
def test_non_finite_observations_are_refused_naming_the_column(name, learned_dir):
    dec, obs = _bound(name, learned_dir, 3)
    for bad in (np.nan, np.inf, -np.inf):
        with pytest.raises(
            zoo.ObservationError,
            match=r"^\S+: observation feature 0 \(ego\[0\]\) is \S*(nan|inf) "
            r"in row 0; observations must be finite$",
        ):
            dec.act(np.full_like(obs, bad))
    one = obs.copy()
    one[2, 12] = np.nan  # a single value, deep in the vector: named by its place in the layout
    with pytest.raises(ValueError, match=r"feature 12 \(blocked\[3\]\) is nan in row 2"):
        dec.act(one)
    with pytest.raises(ValueError, match="must be finite"):
        dec.act(one[2])


@pytest.mark.parametrize("name", MEMBERS)
def test_observations_of_the_wrong_width_are_refused(name, learned_dir):
    dec, obs = _bound(name, learned_dir, 2)
    width = observation_size(EnvConfig())
    for bad in (obs[:, :-1], np.concatenate([obs, obs[:, :1]], axis=1), obs[0, :5]):
        with pytest.raises(
            zoo.ObservationError, match=rf"observations have {bad.shape[-1]} features, expected {width}"
        ):
            dec.act(bad)


@pytest.mark.parametrize("name", MEMBERS)
def test_an_empty_batch_gives_an_empty_int_answer(name, learned_dir):
    dec, obs = _bound(name, learned_dir, 4)
    empty = dec.act(obs[:0])
    assert isinstance(empty, np.ndarray) and empty.shape == (0,) and empty.dtype == np.int64
    # ... and leaves the member's per-row state alone: the next real batch decides as without it.
    fresh, _ = _bound(name, learned_dir, 4)
    np.testing.assert_array_equal(dec.act(obs), fresh.act(obs))


def test_the_oracle_refuses_a_core_of_another_width():
    cfg = EnvConfig.from_dict({"observation": {"vehicles_per_lane": 3}})
    core = OvertakeCore(cfg)
    core.reset(ScenarioDistribution().sample(2, 1))
    with pytest.raises(zoo.ObservationError, match="bound core.s observations have 44 features, expected 34"):
        zoo.load("oracle").bind(core)
    zoo.load("oracle", config=cfg).bind(core)  # its own config's width is fine


def test_legitimate_observations_are_always_finite():
    # Refusing NaN / inf is safe: every shipped suite's observation Box is finite (an empty slot is
    # zeros, not an inf "no vehicle" code), and a run's observations lie in it.
    from overtakezoo.envs.faces.spaces import ego_observation_space
    from overtakezoo.envs.suites import list_suites

    for suite in list_suites():
        box = ego_observation_space(suite.config)
        assert np.isfinite(box.low).all() and np.isfinite(box.high).all(), suite.name
    suite = load_suite("occluded")  # empty slots and late-appearing cars
    core = OvertakeCore(suite.config)
    obs = core.reset(suite.scenarios().take(slice(0, 64)))
    for _ in range(40):
        assert np.isfinite(obs).all()
        obs = core.step(np.ones(core.num, np.int64)).obs
