"""Several automated vehicles on one road: AV-AV crashes for both, aborts that avoid them, NPC-NPC
contacts, emergency braking, the world view of every vehicle, auto-reset and cloning per road."""

import numpy as np
import pytest

from overtakezoo.envs import EnvConfig
from overtakezoo.envs.config import ABORT, FOLLOW, OVERTAKE
from overtakezoo.envs.core import CRASH, SUCCESS, TIMEOUT, OvertakeCore
from overtakezoo.envs.model.controllers import IDM, PLANNER, SCRIPTED_KIND
from overtakezoo.envs.scenarios import Scenarios, make_scenario

L = 4.54


def duel(distance: float = 100.0, gap0: float = 15.0, gap1: float = 30.0, speed: float = 1.0) -> Scenarios:
    """AV 0 at s = 0 behind its lead in lane 0; AV 1, ``distance`` m from AV 0's front, drives towards
    -s in lane 1 behind its own lead (an oncoming NPC ``gap1`` m ahead of it). Goals 150 m away."""
    sc = make_scenario(lead=(gap0, speed), oncoming=[(distance - gap1 - L, speed)], goal=150.0)
    a = sc.to_arrays()
    front = L / 2 + distance
    a.update(
        av_s=np.array([[front + L / 2]]),
        av_d=np.array([[3.5]]),
        av_v=np.array([[sc.ego_v[0]]]),
        av_direction=np.array([[-1]], np.int8),
        av_goal_s=np.array([[front + L / 2 - 150.0]]),
        av_lead=np.array([[1]], np.int16),
    )
    return Scenarios.from_arrays(a)


def drive(core: OvertakeCore, policy, steps: int = 900) -> OvertakeCore:
    for _ in range(steps):
        core.step(policy(core))
        if core.done.all():
            break
    return core


def test_both_overtaking_into_each_other_crash_and_the_crash_names_both():
    core = OvertakeCore()
    core.reset(duel())
    assert core.num == 2 and core.num_roads == 1
    drive(core, lambda c: np.array([OVERTAKE, OVERTAKE]))
    assert core.outcome.tolist() == [CRASH, CRASH]
    assert core.crash_av.tolist() == [1, 0]  # each AV names the other
    assert core.crash_npc.tolist() == [-1, -1]
    assert core.info()["crash_av"].tolist() == [1, 0]


def test_the_same_duel_where_one_aborts_has_no_crash():
    core = OvertakeCore()
    core.reset(duel())
    widest = []

    def policy(c):
        widest.append(c.y[1])
        return np.array([OVERTAKE, ABORT if c.t[1] >= 8.0 else OVERTAKE])

    drive(core, policy)
    assert max(widest) > 1.0  # AV 1 had started its pass before it aborted
    assert core.stats["aborts"].tolist() == [0, 1]
    assert CRASH not in core.outcome.tolist()
    assert core.outcome[0] == SUCCESS


def test_an_av_driving_towards_minus_s_sees_the_road_in_its_own_frame():
    core = OvertakeCore()
    obs = core.reset(duel())
    # Mirrored, AV 1's start is AV 0's: own lane centre, heading along +x, the goal 150 m ahead.
    assert core.y.tolist() == [0.0, 0.0]
    np.testing.assert_allclose(obs[1, 3], obs[0, 3])  # goal distance feature
    geo = core.geometry()  # (B, M + E - 1): the two NPCs, then the other AV
    assert geo["dx"].shape == (2, 3)
    # Each AV sees its own lead ahead in its lane and the other AV coming in the other lane.
    assert geo["same_dir"][0].tolist() == [True, False, False]
    assert geo["same_dir"][1].tolist() == [False, True, False]
    np.testing.assert_allclose(geo["dx"][0, 2], geo["dx"][1, 2])
    assert geo["dy"][0, 2] == pytest.approx(3.5) and geo["dy"][1, 2] == pytest.approx(3.5)


def test_vehicles_lists_every_vehicle_in_world_coordinates_with_its_controller():
    sc = duel()
    core = OvertakeCore()
    core.reset(sc)
    veh = core.vehicles()
    assert veh["kind"].tolist() == [[PLANNER, PLANNER, IDM, IDM]]
    assert veh["direction"].tolist() == [[1.0, -1.0, 1.0, -1.0]]
    np.testing.assert_allclose(veh["s"][0, :2], [0.0, sc.av_s[0, 0]])
    np.testing.assert_allclose(veh["d"][0], [0.0, 3.5, 0.0, 3.5])
    scripted = make_scenario(lead=(10.0, 2.0), lead_behaviour="scripted")
    core.reset(scripted)
    assert core.vehicles()["kind"].tolist() == [[PLANNER, SCRIPTED_KIND]]


def test_npcs_that_touch_both_crash_and_stop_while_the_av_drives_on():
    # Two oncoming cars in lane 1; the rear one is driven (an NPC agent) into the one ahead of it.
    core = OvertakeCore()
    core.reset(make_scenario(lead=None, oncoming=[(80.0, 1.0), (95.0, 1.0)], goal=300.0))
    push = np.array([[np.nan, 3.0]])
    for _ in range(100):
        core.step([FOLLOW], npc_accel=push)
    assert core.npc_crashed.tolist() == [[True, True]]
    assert core.npc_v.tolist() == [[0.0, 0.0]]
    assert not core.done[0]  # not the AV's crash


@pytest.mark.parametrize("braking", [False, True])
def test_emergency_braking_stops_for_a_head_on_car_only_when_enabled(braking):
    cfg = EnvConfig.from_dict(
        {
            "planner": {
                "emergency_braking": braking,
                "enable_prediction": False,
                "modes": {"overtake": {"rollout_id": 4}},
            }
        }
    )
    core = OvertakeCore(cfg)  # OVERTAKE forced into the opposite lane, at a reactive oncoming car
    core.reset(make_scenario(lead=(10.0, 1.0), oncoming=[(60.0, 3.0)], reaction_time=3.0))
    drive(core, lambda c: np.array([OVERTAKE]), 600)
    if braking:
        assert core.outcome[0] == TIMEOUT and core.v[0] == 0.0
        assert core.stats["peak_jerk"][0] > cfg.planner.max_jerk  # the brake skipped the comfort limit
    else:
        assert core.outcome[0] == CRASH and core.crash_npc[0] == 1
        assert core.stats["peak_jerk"][0] <= cfg.planner.max_jerk + 1e-9


def test_a_road_restarts_only_when_every_av_on_it_is_done():
    fresh = Scenarios.concat([duel(), duel(distance=140.0)])
    core = OvertakeCore(auto_reset=True, source=lambda n, rng: fresh.take(np.arange(n) % 2), seed=0)
    core.reset(fresh)
    ended_alone = False
    for _ in range(900):
        clock = core.t.copy()
        res = core.step(np.array([OVERTAKE, OVERTAKE, FOLLOW, FOLLOW]))
        done = core.done.reshape(2, 2)
        ended_alone |= bool((done.any(axis=0) & ~done.all(axis=0)).any())
        if (core.t < clock).any():  # a road was refilled
            break
    assert ended_alone or res.final_obs is not None
    assert res.final_obs is not None and (core.t.reshape(2, 2)[:, 0] == 0).all()  # road 0 restarted, both AVs


def test_a_clone_of_a_multi_av_road_steps_like_the_road():
    core = OvertakeCore()
    core.reset(Scenarios.concat([duel(), duel(distance=140.0)]))
    for _ in range(30):
        core.step(np.array([OVERTAKE, FOLLOW, FOLLOW, OVERTAKE]))
    copy = core.clone([1])
    for _ in range(60):
        core.step(np.array([OVERTAKE, FOLLOW, FOLLOW, OVERTAKE]))
        copy.step(np.array([FOLLOW, OVERTAKE]))
    np.testing.assert_array_equal(copy.x, core.x[[1, 3]])
    np.testing.assert_array_equal(copy.npc_s, core.npc_s[[1]])


def test_scenarios_with_different_numbers_of_avs_do_not_stack():
    with pytest.raises(ValueError, match="automated vehicles"):
        Scenarios.concat([duel(), make_scenario()])
