"""The batched core: configuration, determinism, batch independence and each mode's behaviour."""

import numpy as np
import pytest

from overtakezoo.envs import (
    ABORT,
    CRASH,
    FOLLOW,
    OVERTAKE,
    SUCCESS,
    TIMEOUT,
    ConfigError,
    EnvConfig,
    OvertakeCore,
    ScenarioDistribution,
    Scenarios,
    make_scenario,
)


def run(core, scen, policy, max_steps=700):
    """Step until every row is done; ``policy(core, step) -> modes``. Returns the x/y trajectory."""
    core.reset(scen)
    xs, ys = [], []
    for k in range(max_steps):
        core.step(policy(core, k))
        xs.append(core.x.copy())
        ys.append(core.y.copy())
        if core.done.all():
            break
    return np.array(xs), np.array(ys)


def constant(mode):
    return lambda core, k: np.full(core.num, mode)


def test_config_rejects_unknown_key_and_out_of_range_value():
    with pytest.raises(ConfigError, match="planner.horizon_tme"):
        EnvConfig.from_dict({"planner": {"horizon_tme": 3.0}})
    with pytest.raises(ConfigError, match="dt"):
        EnvConfig.from_dict(dt=-1.0)
    with pytest.raises(ConfigError, match="planner.modes.overtake.rollout_number"):
        EnvConfig.from_dict({"planner": {"modes": {"overtake": {"rollout_number": 99}}}})
    with pytest.raises(ConfigError, match="scenario.lead_speed"):
        EnvConfig.from_dict(scenario={"lead_speed": [3.0, 1.0]})
    cfg = EnvConfig.from_dict({"planner": {"modes": {"follow": {"velocity": 2.0}}}})
    assert cfg.planner.modes["follow"].velocity == 2.0 and cfg.planner.modes["overtake"].rollout_number == 4


def test_same_seed_gives_bit_identical_batches_and_trajectories():
    dist = ScenarioDistribution(oncoming_count=2, follower_count=1)
    a, b = dist.sample(64, 7), dist.sample(64, 7)
    for name, arr in a.to_arrays().items():
        np.testing.assert_array_equal(arr, getattr(b, name), err_msg=name)
    assert not np.array_equal(a.npc_v, dist.sample(64, 8).npc_v)
    xa, ya = run(OvertakeCore(), a, constant(OVERTAKE), 300)
    xb, yb = run(OvertakeCore(), b, constant(OVERTAKE), 300)
    assert np.array_equal(xa, xb) and np.array_equal(ya, yb)


def test_a_scenario_gives_identical_results_alone_and_in_a_batch_of_1000():
    scen = ScenarioDistribution().sample(1000, 3)
    # A mode pattern that switches, so all three parameter sets are exercised.
    policy = lambda core, k: np.where(core.x < 20, FOLLOW, np.where(core.y > 3.0, ABORT, OVERTAKE))  # noqa: E731
    big = OvertakeCore()
    xb, yb = run(big, scen, policy)
    for row in (0, 17, 999):
        one = OvertakeCore()
        x1, y1 = run(one, scen.take([row]), policy)
        steps = x1.shape[0]
        assert np.array_equal(x1[:, 0], xb[:steps, row]) and np.array_equal(y1[:, 0], yb[:steps, row])
        assert one.outcome[0] == big.outcome[row] and one.t[0] == big.t[row]


def test_follow_never_leaves_the_ego_lane_and_never_hits_the_lead():
    scen = ScenarioDistribution().sample(300, 11)
    core = OvertakeCore()
    xs, ys = run(core, scen, constant(FOLLOW))
    assert np.abs(ys).max() < 0.05
    assert not (core.outcome == CRASH).any()
    assert (core.outcome == TIMEOUT).all()  # following never overtakes, so never succeeds


def test_overtake_on_a_clear_road_passes_the_lead_and_returns():
    core = OvertakeCore()
    xs, ys = run(core, make_scenario(lead=(10.0, 1.5), oncoming=[]), constant(OVERTAKE))
    assert core.outcome[0] == SUCCESS
    assert ys.max() > 3.0  # it used the opposite lane
    assert abs(core.y[0]) < 1.0 and core.x[0] > core.npc_s[0, 0]  # and came back ahead of NPC1


def test_abort_returns_behind_the_lead_when_an_oncoming_car_appears_mid_overtake():
    # The oncoming car is hidden (occluded) until 35 m away: the ego has started to pass by then.
    core = OvertakeCore()
    core.reset(make_scenario(lead=(8.0, 2.0), oncoming=[(70.0, 3.0)], reveal=35.0))
    mode, aborted_at = OVERTAKE, None
    for _ in range(600):
        if mode == OVERTAKE and core.geometry()["visible"][0, 1]:
            mode, aborted_at = ABORT, (core.x[0], core.y[0])
        core.step(np.array([mode]))
        if core.done[0]:
            break
    assert aborted_at is not None and aborted_at[1] > 1.5  # the abort happened in the opposite lane
    assert core.outcome[0] != CRASH
    assert abs(core.y[0]) < 0.5 and core.x[0] < core.npc_s[0, 0]  # back in lane, behind NPC1


def test_an_abort_counts_only_when_it_ends_an_overtake_under_way():
    """`aborts` counts OVERTAKE -> ABORT; ABORT chosen while following (a no-op) is not an abort."""
    scen = Scenarios.concat([make_scenario(lead=(8.0, 2.0), oncoming=[(120.0, 3.0)])] * 2)
    # Row 0 flips follow <-> abort every second and never overtakes; row 1 overtakes, aborts at 3 s,
    # overtakes again at 6 s and aborts at 9 s: two aborts.
    core = OvertakeCore()
    core.reset(scen)
    for k in range(120):
        t = k * core.cfg.dt
        row1 = OVERTAKE if t < 3.0 or 6.0 <= t < 9.0 else ABORT
        core.step(np.array([ABORT if int(t) % 2 else FOLLOW, row1]))
    assert core.stats["aborts"].tolist() == [0, 2]


def test_overtake_held_blindly_into_oncoming_traffic_crashes_with_the_oncoming_car():
    core = OvertakeCore()
    run(core, make_scenario(lead=(6.0, 2.0), oncoming=[(35.0, 3.0)]), constant(OVERTAKE))
    # Whether the planner starts the pass depends on the horizon; hold the opposite lane explicitly.
    core = OvertakeCore(EnvConfig.from_dict({"planner": {"modes": {"overtake": {"rollout_id": 4}}}}))
    run(core, make_scenario(lead=(6.0, 2.0), oncoming=[(45.0, 3.0)]), constant(OVERTAKE))
    assert core.outcome[0] == CRASH
    assert core.crash_npc[0] == 1 and core.crash_lane[0] == 1  # NPC2, the opposite lane


def test_auto_reset_replaces_finished_rows_with_fresh_scenarios():
    dist = ScenarioDistribution(time_limit=3.0)
    core = OvertakeCore(auto_reset=True, source=lambda n, rng: dist.sample(n, rng), seed=0)
    core.reset(dist.sample(8, 1))
    finished = 0
    for _ in range(80):
        res = core.step(np.zeros(8, int))
        finished += res.truncated.sum()
        if res.truncated.any():
            assert res.final_obs is not None
            assert (core.t[res.truncated] == 0).all()  # the replacement starts at t = 0
    assert finished >= 16


def test_oriented_box_collision_detects_overlap_and_clearance():
    scen = make_scenario(lead=(0.1, 0.0), oncoming=[])
    core = OvertakeCore()
    core.reset(scen)
    assert not core.contacts()[0, 0]  # 10 cm apart, aligned: clear
    core.psi[:] = 0.3  # the same ego rotated: its front corner reaches the lead
    assert core.contacts()[0, 0]
    core.x[:] -= 2.0
    assert not core.contacts()[0, 0]


def test_scenarios_concat_pads_npc_slots():
    a = make_scenario(lead=(10.0, 2.0), oncoming=[])
    b = make_scenario(lead=(10.0, 2.0), oncoming=[(50.0, 2.0), (90.0, 2.0)])
    both = Scenarios.concat([a, b])
    assert both.num == 2 and both.num_npcs == 3
    assert both.npc_present.tolist() == [[True, False, False], [True, True, True]]
