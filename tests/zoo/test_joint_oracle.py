"""The joint oracle: a privileged upper bound on multi-AV roads that plans every AV of a road together.
It drives suites the single-ego oracle refuses, beats the zoo's members in self-play on the same
roads, and its choice for a road does not depend on which other roads share the batch."""

from __future__ import annotations

import numpy as np
import pytest

from overtakezoo import zoo
from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.run.runner import run_indices
from overtakezoo.envs import SUCCESS
from overtakezoo.envs.suites import load_suite
from overtakezoo.zoo.members.joint_oracle import joint_plans


def joint_success(per: dict[str, np.ndarray], num_avs: int) -> np.ndarray:
    return (per["outcome"].reshape(num_avs, -1) == SUCCESS).all(axis=0)


def test_every_joint_plan_once():
    plans = joint_plans(3)
    assert plans.shape == (8, 3) and len({tuple(p) for p in plans.tolist()}) == 8


@pytest.mark.parametrize("suite_name, count", [("duel", 40), ("platoon", 12)])
def test_it_succeeds_jointly_at_least_as_often_as_any_member_in_self_play(suite_name, count):
    suite = load_suite(suite_name)
    idx = np.arange(count)
    e = suite.num_avs
    oracle = run_indices(suite, zoo.load("joint-oracle"), idx)
    best = joint_success(oracle, e)
    assert (oracle["crash_av"] < 0).all()  # it never drives two of its AVs into each other
    for name in ("rule-fsm", "fuzzy", "ps-dqn"):
        member = joint_success(run_indices(suite, zoo.load(name), idx), e)
        assert best.sum() >= member.sum(), f"{name} succeeds jointly on more {suite_name} roads than the joint oracle"
    assert best.mean() > 0.5


def test_a_roads_plan_does_not_depend_on_the_other_roads_in_its_batch():
    suite = load_suite("duel")
    idx = np.arange(12)
    whole = run_indices(suite, zoo.load("joint-oracle"), idx)
    chunked = run_indices(suite, zoo.load("joint-oracle"), idx, chunk_size=5)
    for key in ("outcome", "episode_time", "switches"):
        np.testing.assert_array_equal(whole[key], chunked[key])


def test_the_single_ego_oracle_is_refused_on_a_multi_av_suite_naming_the_joint_one():
    with pytest.raises(UserError, match="joint-oracle plans every AV of a road"):
        run_indices(load_suite("duel"), zoo.load("oracle"), np.arange(2))


def test_plan_re_plans_the_roads_of_the_rows_asked_as_act_batch_does():
    """``plan`` (the DAgger labeller) gives the rows asked the modes that ``act_batch`` gives them,
    even on a road it verified (trust off), and leaves the other roads' decisions untouched."""
    from overtakezoo.envs.core import OvertakeCore

    suite = load_suite("duel")
    sc = suite.scenarios().take(np.arange(6))
    planned, acting = (zoo.load("joint-oracle", suite.config, trust_verified=False) for _ in range(2))
    cores = [OvertakeCore(suite.config) for _ in range(2)]
    obs = [c.reset(sc) for c in cores][1]
    for o, c in zip((planned, acting), cores, strict=True):
        o.bind(c)
    roads = cores[0].num_roads
    rows = np.array([1, roads + 4])  # AV 0 of road 1, AV 1 of road 4
    others = np.isin(np.arange(cores[0].num) % roads, [1, 4], invert=True)
    seen = set()
    for _ in range(8):  # re-planned each second for 8 s: the AVs pull out, so the plans change
        before = planned.decision.copy()
        got = planned.plan(rows)
        every = acting.act_batch(obs)
        np.testing.assert_array_equal(got, every[rows])
        np.testing.assert_array_equal(planned.decision[others], before[others])
        seen.update(every[rows].tolist())
        for _ in range(acting.action_repeat):  # both cores move on under the acting oracle's modes
            cores[0].advance(every)
            obs = cores[1].step(every).obs
    assert len(seen) > 1  # the test saw the plan change
