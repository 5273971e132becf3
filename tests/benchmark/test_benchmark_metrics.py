"""Metrics: Wilson and bootstrap intervals, Table I rows from per-scenario arrays."""

import numpy as np
import pytest

from overtakezoo.benchmark.results.metrics import bootstrap_mean, crash_same_scenarios, render_table, summarize, wilson


def test_wilson_known_values():
    # Reference values: statsmodels proportion_confint(k, n, method="wilson").
    assert wilson(8, 10) == pytest.approx((0.4901624715, 0.9433178485), abs=1e-9)
    assert wilson(0, 10) == pytest.approx((0.0, 0.2775327999), abs=1e-9)
    assert all(np.isnan(wilson(0, 0)))


def test_bootstrap_is_seeded_and_brackets_the_mean():
    x = np.random.default_rng(0).normal(5.0, 1.0, 500)
    a, b = bootstrap_mean(x, 1), bootstrap_mean(x, 1)
    assert a == b and a[0] < x.mean() < a[1]
    assert a[1] - a[0] == pytest.approx(2 * 1.96 / np.sqrt(500), rel=0.2)
    assert all(np.isnan(bootstrap_mean(np.array([]), 1)))


def _per(outcome, crash_npc):
    n = len(outcome)
    z = np.zeros(n)
    return {
        "outcome": np.array(outcome),
        "crash_npc": np.array(crash_npc),
        "crash_lane": np.where(np.array(crash_npc) == 1, 1, np.where(np.array(crash_npc) == 0, 0, -1)),
        "completion_time": np.where(np.array(outcome) == 1, 25.0, np.nan),
        "episode_time": z + 30,
        "aborts": np.zeros(n, int),
        "switches": np.zeros(n, int),
        "opposite_time": z,
        "min_ttc": z + np.inf,
        "peak_lat_accel": z,
        "peak_jerk": z,
        "npc1_speed": np.linspace(1, 3, n),
        "npc2_speed": z + 2,
    }


def test_table1_rows():
    per = _per([1, 1, 2, 2, 2, 3], [-1, -1, 0, 1, 1, -1])
    s = summarize(per, seed=3)
    assert s["success_rate"]["value"] == pytest.approx(2 / 6)
    assert s["crash_share_npc1"]["value"] == pytest.approx(1 / 3) and s["crash_share_npc1"]["n"] == 3
    assert s["crash_share_npc2"]["value"] == pytest.approx(2 / 3)
    assert s["completion_time"]["value"] == 25.0
    assert s["npc1_speed_failed"]["value"] == pytest.approx(np.linspace(1, 3, 6)[2:].mean())
    assert s["min_ttc"]["value"] is None  # no scenario was ever on a collision course
    other = _per([2, 1, 2, 1, 1, 3], [0, -1, 1, -1, -1, -1])
    same = crash_same_scenarios(per, other)
    assert same["k"] == 1 and same["value"] == pytest.approx(1 / 6)  # both crashed only in scenario 2
    table = render_table([("a", s), ("b", summarize(other, 3))], paired=same)
    assert "crash in the same scenarios" in table and "16.7 %" in table
