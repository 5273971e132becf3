"""The RSS shield: it vetoes an overtake the RSS distance forbids, aborts one under way while the lead
is not yet passed, lets safe decisions through, and on table1 removes rule-fsm's head-on crashes."""

from __future__ import annotations

import numpy as np
import pytest

from overtakezoo import zoo
from overtakezoo.benchmark.run.runner import run_indices
from overtakezoo.envs import ABORT, CRASH, FOLLOW, OVERTAKE, SUCCESS, EnvConfig, observation_layout
from overtakezoo.envs.model.observation import SLOT_FEATURES
from overtakezoo.envs.rss import RSSParams, safe_distance_opposite_direction
from overtakezoo.envs.suites import load_suite
from overtakezoo.zoo.base import ConstantDecider
from overtakezoo.zoo.members.shield import REQUIRED_GAP, Shielded

CFG = EnvConfig()


def observation(
    mode: int, v_e: float, lead_dx: float, v_lead: float, onc_dx: float | None, v_onc: float, lateral: float = 0.0
) -> np.ndarray:
    """One observation with the ego, its lead and (optionally) one oncoming vehicle, in SI units."""
    lay, oc = observation_layout(CFG), CFG.observation
    obs = np.zeros((1, lay["opposite_lane"].stop), np.float32)
    ego = obs[0, lay["ego"]]
    ego[0], ego[2], ego[3], ego[4], ego[5] = v_e / oc.speed_scale, lateral, 1.0, 15 / 3.6 / oc.speed_scale, 1.0
    obs[0, lay["mode"].start + mode] = 1.0
    lane = obs[0, lay["ego_lane"]].reshape(-1, SLOT_FEATURES)
    lane[0] = [1.0, lead_dx / oc.position_scale, 0.0, (v_lead - v_e) / oc.speed_scale, 0.0]
    if onc_dx is not None:
        opp = obs[0, lay["opposite_lane"]].reshape(-1, SLOT_FEATURES)
        opp[0] = [1.0, onc_dx / oc.position_scale, 1.0, (-v_onc - v_e) / oc.speed_scale, 0.0]
    return obs


def test_the_veto_threshold_is_the_rss_distance_left_at_the_end_of_the_pass():
    shield = Shielded(ConstantDecider(OVERTAKE, "go", CFG))
    v = 15 / 3.6  # the shuttle at its cap behind a lead at half its speed: a cruise-only pass
    lead_dx, v_lead, v_onc = 12.0, v / 2, 3.0
    need = lead_dx + shield.half_lengths + REQUIRED_GAP
    t_pass = need / (v - v_lead)
    t_out = t_pass + shield.p.lateral_return_time
    p = RSSParams()
    rss = float(
        safe_distance_opposite_direction(
            v, v_onc, p.response_time, p.ego_accel_max, p.ego_brake_min, p.other_accel_max, p.other_brake_min_correct
        )
    )
    threshold = v * t_out + v_onc * t_out + rss  # bumper gap to the oncoming car that just suffices
    for gap, allowed in ((threshold + 0.5, True), (threshold - 0.5, False)):
        obs = observation(FOLLOW, v, lead_dx, v_lead, gap + shield.half_lengths, v_onc)
        assert shield.act(obs[0]) == (OVERTAKE if allowed else FOLLOW), gap
    # Nothing oncoming in view, or no lead to pass: nothing to veto.
    assert shield.act(observation(FOLLOW, v, lead_dx, v_lead, None, 0.0)[0]) == OVERTAKE


def test_an_overtake_under_way_is_aborted_until_the_lead_is_passed():
    shield = Shielded(ConstantDecider(OVERTAKE, "go", CFG))
    v = 15 / 3.6
    close = 30.0  # an oncoming car 30 m ahead: no pass can keep the RSS distance
    beside = observation(OVERTAKE, v, 2.0, v / 2, close, 4.0, lateral=1.0)
    assert shield.act(beside[0]) == ABORT
    passed = observation(OVERTAKE, v, -shield.half_lengths - 1.0, v / 2, close, 4.0, lateral=1.0)
    assert shield.act(passed[0]) == OVERTAKE  # the lead is behind: completing is the way out
    # A decider that follows or aborts is never overridden.
    for mode in (FOLLOW, ABORT):
        assert Shielded(ConstantDecider(mode, "m", CFG)).act(beside[0]) == mode


def test_shield_names_and_registry():
    d = zoo.load("shielded:rule-fsm")
    assert d.name == "rule-fsm+shield" and zoo.load("rule-fsm+shield").name == d.name
    assert "dqn+shield" in zoo.known_names() and not d.privileged
    with pytest.raises(zoo.UnknownDecider):
        zoo.load("shielded:no-such-decider")


def test_on_table1_the_shield_removes_rule_fsms_head_on_crashes():
    suite = load_suite("table1")
    idx = np.arange(300)
    plain = run_indices(suite, zoo.load("rule-fsm", suite.config), idx)["outcome"]
    shielded = run_indices(suite, zoo.load("rule-fsm+shield", suite.config), idx)["outcome"]
    assert np.mean(plain == CRASH) > 0.15  # OpenPlanner's FSM has no abort: a quarter of table1 crashes
    assert np.mean(shielded == CRASH) < 0.01 and np.mean(shielded == SUCCESS) > np.mean(plain == SUCCESS)
