"""Scripted NPCs (the paper's OpenSCENARIO traffic) drive their speed profile blind to the ego;
reactive (IDM) NPCs, the env's default, brake for an ego in their lane."""

import numpy as np
import pytest

from overtakezoo.envs import CRASH, OVERTAKE, ConfigError, EnvConfig, OvertakeCore, ScenarioDistribution, make_scenario

PLANNER = {"planner": {"enable_prediction": False}}  # the planner does not stop the ego: it drives into NPC2


def overtake_into_npc2(behaviour):
    """Always overtake with an oncoming NPC2 close ahead; NPC2's speed every step until the episode ends."""
    scen = make_scenario(lead=(8.0, 1.0), oncoming=[(45.0, 2.0)], oncoming_behaviour=behaviour, reaction_time=0.5)
    core = OvertakeCore(EnvConfig.from_dict(PLANNER))
    core.reset(scen)
    speeds, blocked = [], []
    for _ in range(400):
        blocked.append(abs(core.y[0] - scen.lane_width[0]) < 1.82)  # ego overlaps NPC2's lane
        core.step(np.array([OVERTAKE]))
        speeds.append(core.npc_v[0, 1])
        if core.done[0]:
            break
    return core, np.array(speeds), np.array(blocked)


def test_a_scripted_oncoming_npc_keeps_its_speed_while_the_ego_blocks_its_lane():
    core, speeds, blocked = overtake_into_npc2("scripted")
    assert core.outcome[0] == CRASH and core.crash_npc[0] == 1
    assert blocked.sum() > 10  # the ego sat in NPC2's lane for over a second before the crash
    np.testing.assert_array_equal(speeds, 2.0)  # unchanged up to and including the crash step


def test_a_reactive_oncoming_npc_brakes_for_the_ego_in_its_lane():
    core, speeds, blocked = overtake_into_npc2("idm")
    assert blocked.sum() > 10
    assert speeds.min() < 1.0  # it braked hard once it noticed the ego


def test_scripted_is_a_distribution_setting_for_lead_and_oncoming():
    dist = ScenarioDistribution.from_dict(
        {"lead_behaviour": "scripted", "oncoming_behaviour": "scripted", "oncoming_count": 2}
    )
    scen = dist.sample(5, 0)
    assert (scen.npc_behaviour == 2).all()
    # The same draw as with reactive NPCs: only the behaviour column differs.
    idm = ScenarioDistribution.from_dict({"oncoming_count": 2}).sample(5, 0)
    np.testing.assert_array_equal(scen.npc_s, idm.npc_s)
    with pytest.raises(ConfigError, match="scenario.oncoming_behaviour"):
        ScenarioDistribution.from_dict({"oncoming_behaviour": "speedup"})
