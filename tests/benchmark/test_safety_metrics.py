"""Safety metrics (issue 22, docs/metrics.md): the RSS distances in closed form and against ad-rss,
each monitor metric on hand-built states whose values follow by hand, batch independence on the
real core, and results files with and without the safety arrays."""

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.results.results import SAFETY_PER_SCENARIO, Results
from overtakezoo.benchmark.run.runner import run_indices, run_suite
from overtakezoo.benchmark.safety import (
    RSSParams,
    SafetyMonitor,
    safe_distance_opposite_direction,
    safe_distance_same_direction,
)
from overtakezoo.envs.config import ABORT, FOLLOW, OVERTAKE
from overtakezoo.envs.suites import load_suite
from overtakezoo.zoo.base import load

P = RSSParams()
W, EGO_W, HALF_LEN = 3.5, 1.82, 4.54  # lane width, ego width, half-length sum of two 4.54 m cars
V_E, V_O, V_L = 4.0, 2.0, 2.0  # ego, oncoming and lead speeds (constant)
# Def. 2 by hand at these speeds: ego (wrong lane) v_rho = 4 + 1.5 = 5.5 -> (4 + 5.5) / 2 + 5.5^2 / 4,
# oncoming (correct lane) v_rho = 2 + 1 = 3 -> (2 + 3) / 2 + 3^2 / (2 * 1.125).
D2 = 4.75 + 7.5625 + 2.5 + 4.0  # 18.8125 m
# Def. 1, the lead (2 m/s) behind the ego (4 m/s): 2 + 0.5 + 3^2 / 3 - 4^2 / 10.
D1_BEHIND = 2.0 + 0.5 + 3.0 - 1.6  # 3.9 m


def test_rss_distances_match_the_paper_by_hand():
    # Def. 1 with rho 1 s, a_accel 2, b_min 4, b_max 8: 12 + 1 + 14^2 / 8 - 10^2 / 16 = 31.25 m.
    assert safe_distance_same_direction(12.0, 10.0, 1.0, 2.0, 4.0, 8.0) == pytest.approx(31.25)
    # [x]_+: a slow rear car behind a fast front car needs no distance.
    assert safe_distance_same_direction(0.0, 10.0, 1.0, 2.0, 4.0, 8.0) == 0.0
    # Def. 2: (10 + 12) / 2 + 12^2 / 6 + (12 + 14) / 2 + 14^2 / 8 = 11 + 24 + 13 + 24.5 = 72.5 m.
    assert safe_distance_opposite_direction(12.0, 10.0, 1.0, 2.0, 4.0, 2.0, 3.0) == pytest.approx(72.5)
    assert safe_distance_opposite_direction(
        V_E, V_O, P.response_time, P.ego_accel_max, P.ego_brake_min, P.other_accel_max, P.other_brake_min_correct
    ) == pytest.approx(D2)


def test_rss_distances_agree_with_ad_rss_on_a_grid():
    ad_rss = pytest.importorskip("ad_rss")
    phys, rss = ad_rss.physics, ad_rss.rss

    def state(v, rho, accel, b_min, b_max, b_correct, correct):
        o = rss.core.RelativeObjectState()
        o.object_type = rss.world.ObjectType.OtherVehicle
        d = o.dynamics
        d.alpha_lon.accel_max, d.alpha_lon.brake_min = phys.Acceleration(accel), phys.Acceleration(-b_min)
        d.alpha_lon.brake_max, d.alpha_lon.brake_min_correct = phys.Acceleration(-b_max), phys.Acceleration(-b_correct)
        d.alpha_lat.accel_max, d.alpha_lat.brake_min = phys.Acceleration(0.2), phys.Acceleration(-0.8)
        d.response_time, d.max_speed_on_acceleration = (
            phys.Duration(rho),
            phys.Speed(100.0),
        )  # (its largest valid value; above every speed here)
        d.lateral_fluctuation_margin, d.min_longitudinal_safety_distance = phys.Distance(0.0), phys.Distance(0.0)
        u = d.unstructured_settings
        u.pedestrian_turning_radius, u.drive_away_max_angle = phys.Distance(2.0), phys.Angle(2.4)
        u.vehicle_yaw_rate_change, u.vehicle_min_radius = phys.AngularAcceleration(0.3), phys.Distance(3.5)
        u.vehicle_trajectory_calculation_step = phys.Duration(0.2)
        d.unstructured_settings = u
        o.dynamics = d
        s = o.structured_object_state
        s.velocity.speed_lon_min = s.velocity.speed_lon_max = phys.Speed(v)
        s.velocity.speed_lat_min = s.velocity.speed_lat_max = phys.Speed(0.0)
        s.is_in_correct_lane = correct
        s.distance_to_enter_intersection = s.distance_to_leave_intersection = phys.Distance(0.0)
        o.structured_object_state = s
        us = o.unstructured_object_state
        us.yaw, us.yaw_rate, us.steering_angle = phys.Angle(0.0), phys.AngularVelocity(0.0), phys.Angle(0.0)
        us.dimension.length, us.dimension.width = phys.Distance(4.54), phys.Distance(1.82)
        us.center_point.x = us.center_point.y = phys.Distance(0.0)
        us.speed_range.minimum = us.speed_range.maximum = phys.Speed(v)
        o.unstructured_object_state = us
        return o

    ego = (P.response_time, P.ego_accel_max, P.ego_brake_min, P.ego_brake_max, P.ego_brake_min)
    other = (P.response_time, P.other_accel_max, P.other_brake_min, P.other_brake_max, P.other_brake_min_correct)
    worst = 0.0
    for v_ego in (0.0, 1.0, 25 / 6, 8.0, 13.9):
        for v_other in (0.0, 0.5, 2.0, 3.0, 12.5):
            got, want = phys.Distance(0.0), phys.Distance(0.0)
            # The ego behind (rear) the other; then the ego in the wrong lane against the other in its own.
            assert rss.structured.calculateSafeLongitudinalDistanceSameDirection(
                state(v_other, *other, True), state(v_ego, *ego, True), got
            )
            mine = safe_distance_same_direction(v_ego, v_other, ego[0], ego[1], ego[2], other[3])
            worst = max(worst, abs(float(got.mDistance) - mine))
            assert rss.structured.calculateSafeLongitudinalDistanceOppositeDirection(
                state(v_other, *other, True), state(v_ego, *ego, False), want
            )
            mine = safe_distance_opposite_direction(v_ego, v_other, ego[0], ego[1], ego[2], other[1], other[4])
            worst = max(worst, abs(float(want.mDistance) - mine))
    assert worst < 1e-6  # ad-rss's Distance keeps 1e-3 m precision in checks; the value itself is a double


class StubCore:
    """Just what the monitor reads, with hand-set states: per row an ego in lane y at V_E, one
    oncoming car (slot 0) closing from ``gap0`` at V_E + V_O, and the passed lead (slot 1) ``lead_gap``
    behind the ego, in the ego lane at V_L. ``y[k]``, ``mode[k]``: each row's lateral position and
    mode after step k."""

    def __init__(self, gap0, lead_gap, y, mode, dt=0.1):
        self.gap0, self.lead_gap = np.asarray(gap0, float), np.asarray(lead_gap, float)
        self.ys, self.modes, self.k = np.asarray(y, float), np.asarray(mode, np.int64), 0
        b = self.gap0.shape[0]
        self.num_avs, self.cfg = 1, SimpleNamespace(dt=dt)
        self.scen = SimpleNamespace(lane_width=np.full(b, W), ego_width=np.full(b, EGO_W))
        self.v, self.psi = np.full(b, V_E), np.zeros(b)
        self.done, self.mode, self.t, self.y = np.zeros(b, bool), np.full(b, FOLLOW), np.zeros(b), np.zeros(b)

    def step(self):
        self.k += 1
        self.t = np.full(self.gap0.shape, self.k * self.cfg.dt)
        self.y, self.mode = self.ys[self.k - 1], self.modes[self.k - 1]

    def step_geometry(self):
        b, t = self.gap0.shape[0], self.t
        onc_dx = self.gap0 + HALF_LEN - (V_E + V_O) * t
        lead_dx = -(self.lead_gap + HALF_LEN) * np.ones(b)
        return {
            "dx": np.stack([onc_dx, lead_dx]),
            "half_len": np.full((2, b), HALF_LEN),
            "d": np.stack([np.full(b, W), np.zeros(b)]),
            "same_dir": np.stack([np.zeros(b, bool), np.ones(b, bool)]),
            "v_along": np.stack([np.full(b, -V_O), np.full(b, V_L)]),
            "visible": np.ones((2, b), bool),
            "present": np.ones((2, b), bool),
        }


def _monitor(core, steps):
    mon = SafetyMonitor()
    mon.begin_chunk(core)
    for _ in range(steps):
        core.step()
        mon.record_step(core)
    return mon.end_chunk(core)


def _hand_built(rows=(0, 1, 2)):
    """Row 0: 30 steps in the opposite lane overtaking, then back in lane 10 m ahead of the lead.
    Row 1: the same, aborting at step 5, back in lane at step 31 only 3 m ahead (too close).
    Row 2: never leaves its lane."""
    n = 32
    y = np.zeros((n, 3))
    y[:30, :2] = W  # opposite-lane centre for steps 1..30
    mode = np.full((n, 3), FOLLOW)
    mode[:30, 0] = OVERTAKE
    mode[:4, 1], mode[4:, 1] = OVERTAKE, ABORT
    rows = list(rows)
    return StubCore(np.array([30.0, 30.0, 30.0])[rows], np.array([10.0, 3.0, 10.0])[rows], y[:, rows], mode[:, rows]), n


def test_each_safety_metric_on_hand_built_states_matches_the_closed_form():
    core, n = _hand_built()
    out = _monitor(core, n)
    # The gap after step k is 30 - 0.6 k: Def. 2 (18.8125 m) is violated from k = 19 (18.6 m) on.
    np.testing.assert_allclose(out["rss_first_violation"], [1.9, 1.9, np.nan])
    np.testing.assert_allclose(out["rss_violation_share"], [12 / 30, 12 / 30, np.nan])
    np.testing.assert_allclose(out["rss_worst_margin"], [12.0 - D2, 12.0 - D2, np.nan])
    # Head-on TTC: least gap 12 m at closing 6 m/s.
    np.testing.assert_allclose(out["min_headon_ttc"], [2.0, 2.0, np.inf])
    # Merge back: 10 m ahead of the lead > its Def. 1 distance 3.9 m; 3 m < 3.9 m. PET = gap / 2 m/s.
    np.testing.assert_array_equal(out["rss_merge_violation"], [0, 1, -1])
    np.testing.assert_allclose(out["cutin_pet"], [5.0, 1.5, np.nan])
    # Unsafe to complete from the first step: back in lane takes the full 2 s lateral return (the
    # lead is passed), the Def.-2 distance is reached after (29.4 - D2) / 6 = 1.76 s < 2 s.
    # Row 1 decided the abort on the state at t = 0.4 s: delay 0.3 s; that state's margin to the
    # point of no return was (27.6 - D2) / 6 - 2 = -0.535 s < 0: late. Row 0 never aborted and
    # violated RSS: late too.
    np.testing.assert_allclose(out["abort_delay"], [np.nan, 0.3, np.nan], atol=1e-12)
    np.testing.assert_array_equal(out["late_abort"], [1, 1, -1])
    # Least margin over the overtake: row 0 overtakes through step 30, where RSS is violated (no
    # time left: 0 - 2 s); row 1 overtakes steps 1-4, least at step 4.
    np.testing.assert_allclose(out["ponr_margin"], [-2.0, (27.6 - D2) / 6 - 2.0, np.nan])


def test_a_timely_abort_and_a_safe_pass_are_not_late():
    # The oncoming car 200 m away: completing (2 s) is safe; the Def.-2 distance is far.
    y = np.zeros((12, 1))
    y[:10] = W
    core = StubCore([200.0], [10.0], y, np.full((12, 1), OVERTAKE))
    out = _monitor(core, 12)
    assert out["late_abort"][0] == -1 and math.isnan(out["abort_delay"][0])
    assert out["rss_violation_share"][0] == 0.0 and math.isnan(out["rss_first_violation"][0])
    # Least at step 10: t_rss = (200 - 6 - D2) / 6, minus the 2 s lateral return.
    assert out["ponr_margin"][0] == pytest.approx((200.0 - 6.0 - D2) / 6 - 2.0)


def test_the_monitor_gives_each_row_the_value_it_gets_alone():
    core, n = _hand_built()
    together = _monitor(core, n)
    for row in range(3):
        alone = _monitor(_hand_built([row])[0], n)
        for key, value in together.items():
            np.testing.assert_array_equal(alone[key], value[row : row + 1], err_msg=key)


def test_safety_arrays_of_a_batch_equal_those_of_rows_run_alone_on_the_core():
    suite = load_suite("table1")
    decider = load("rule-fsm", suite.config)
    rows = np.array([3, 17, 250, 1999])
    batch = run_indices(suite, decider, rows)
    assert set(SAFETY_PER_SCENARIO) <= set(batch)
    assert (batch["opposite_time"] > 0).any()  # the sample exercises the opposite lane
    for i, row in enumerate(rows):
        alone = run_indices(suite, decider, np.array([row]))
        for key in SAFETY_PER_SCENARIO:
            np.testing.assert_array_equal(alone[key], batch[key][i : i + 1], err_msg=key)


def test_multi_av_runs_give_one_safety_value_per_av():
    suite = load_suite("duel")
    res = run_suite(suite, load("rule-fsm", suite.config), limit=3, progress=False)
    for key in SAFETY_PER_SCENARIO:
        assert res.per[key].shape == (3 * res.num_avs,), key
    assert "rss_violation_share" in res.summary["per_av"][1]


def test_results_files_without_safety_arrays_still_load_and_partial_ones_are_refused(tmp_path):
    suite = load_suite("table1")
    decider = load("rule-fsm", suite.config)
    new = run_suite(suite, decider, limit=20, progress=False)
    old = run_suite(suite, decider, limit=20, progress=False, safety=False)
    # Recording the safety metrics changes nothing that existed before, arrays or summary.
    for key in old.per:
        np.testing.assert_array_equal(old.per[key], new.per[key], err_msg=key)
    assert {k: v for k, v in new.summary.items() if k in old.summary} == old.summary
    assert not set(SAFETY_PER_SCENARIO) & set(old.summary)
    for res, name in ((old, "old.json"), (new, "new.json")):
        loaded = Results.load(res.save(tmp_path / name))
        assert set(loaded.per) == set(res.per) and loaded.summary == json.loads(json.dumps(res.summary))
    doc = json.loads((tmp_path / "new.json").read_text())
    del doc["scenarios"]["ponr_margin"]
    with pytest.raises(UserError, match="scenarios.ponr_margin: missing"):
        Results.from_json(json.dumps(doc))


def test_rss_params_are_range_checked_settings():
    assert RSSParams.from_dict({"response_time": 0.5}).response_time == 0.5
    with pytest.raises(ValueError, match="safety.response_tme"):
        RSSParams.from_dict({"response_tme": 0.5})
    with pytest.raises(ValueError, match="safety.ego_brake_min"):
        RSSParams(ego_brake_min=-1.0)
