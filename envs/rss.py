"""RSS safe longitudinal distances (Shalev-Shwartz, Shammah, Shashua 2017, arXiv:1708.06374) and the
parameters they are measured with, scaled to this simulator. Pure numpy, any broadcastable shapes.

Definition 1 (same direction, rear car c_r behind front car c_f, speeds v_r, v_f >= 0):

    d_min = [ v_r rho + a_accel rho^2 / 2 + (v_r + rho a_accel)^2 / (2 b_min) - v_f^2 / (2 b_max) ]_+

Definition 2 (opposite directions, c_1 in its correct lane, c_2 in the wrong lane, v_i >= 0 towards
each other, v_{i,rho} = v_i + rho a_accel,i):

    d_min = (v_1 + v_{1,rho}) rho / 2 + v_{1,rho}^2 / (2 b_min_correct)
          + (v_2 + v_{2,rho}) rho / 2 + v_{2,rho}^2 / (2 b_min)

ad-rss-lib (``ad::rss::structured::calculateSafeLongitudinalDistance{Same,Opposite}Direction``)
computes the same two formulas with per-vehicle dynamics; tests/benchmark/test_safety_metrics.py checks them
against it on a grid.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from overtakezoo.envs.config import ConfigError, bounded, check_ranges
from overtakezoo.envs.typed import build


@dataclass(frozen=True)
class RSSParams:
    """RSS parameters of the safety metrics (docs/metrics.md, "RSS parameters").

    ad-rss-lib's passenger-car values assume accelerations this simulator's vehicles cannot reach,
    and an RSS bound that assumes more than a vehicle can do is no bound, so each value is the
    simulator's own limit (envs/config.py defaults, no shipped suite overrides them):

    - ``response_time`` rho = 1 s: the planner's jerk limit (3 m/s^3) needs
      ~0.7 s to build a 2 m/s^2 brake, and NPCs react after 0.5-1 s (scenario reaction_time).
    - the ego (the planner): ``ego_accel_max`` 1.5 (the overtake mode's acceleration),
      ``ego_brake_min`` 2.0 (planner.comfortable_braking, the brake it always applies),
      ``ego_brake_max`` 5.0 (planner.max_braking).
    - the others (IDM NPCs, and other AVs alike): ``other_accel_max`` 1.0 (npc.max_acceleration),
      ``other_brake_min`` 1.5 (npc.comfortable_braking), ``other_brake_max`` 6.0 (npc.max_braking),
      ``other_brake_min_correct`` 1.125 = 1.5 * 3/4 (the car in its own lane is asked to brake less
      than the one in the wrong lane, the paper's a_min,brake,correct < a_min,brake).
    - ``lateral_return_time`` 2.0 s: a full lane change back from the opposite lane's centre (the
      planner's roll-in is v * 1 s + 4 m + 1 m tip margin, 9.2 m or 2.2 s at 15 km/h); used by the
      point-of-no-return and abort metrics only.
    """

    response_time: float = bounded(1.0, 0.0, 10.0, "s")
    ego_accel_max: float = bounded(1.5, 0.0, 15.0, "m/s^2")
    ego_brake_min: float = bounded(2.0, 0.01, 15.0, "m/s^2")
    ego_brake_max: float = bounded(5.0, 0.01, 15.0, "m/s^2")
    other_accel_max: float = bounded(1.0, 0.0, 15.0, "m/s^2")
    other_brake_min: float = bounded(1.5, 0.01, 15.0, "m/s^2")
    other_brake_min_correct: float = bounded(1.125, 0.01, 15.0, "m/s^2")
    other_brake_max: float = bounded(6.0, 0.01, 15.0, "m/s^2")
    lateral_return_time: float = bounded(2.0, 0.0, 60.0, "s")

    def __post_init__(self) -> None:
        check_ranges(self, "safety.")

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> RSSParams:
        return build(cls, data or {}, error=ConfigError, prefix="safety.", coerce=True, root="safety")


def safe_distance_same_direction(
    v_rear: Any, v_front: Any, rho: float, accel_max: float, brake_min: float, brake_max: float
) -> np.ndarray:
    """RSS Definition 1 (m): the rear car accelerates at ``accel_max`` for ``rho`` then brakes at
    ``brake_min`` (its parameters); the front car brakes at ``brake_max`` (its own)."""
    v_r, v_f = np.maximum(v_rear, 0.0), np.maximum(v_front, 0.0)
    v_r_rho = v_r + rho * accel_max
    d = v_r * rho + 0.5 * accel_max * rho * rho + v_r_rho * v_r_rho / (2.0 * brake_min) - v_f * v_f / (2.0 * brake_max)
    return np.maximum(d, 0.0)


def _stopping(v: Any, rho: float, accel_max: float, brake: float) -> np.ndarray:
    """Distance covered while accelerating for ``rho`` then braking to a stop (one car of Def. 2)."""
    v = np.maximum(v, 0.0)
    v_rho = v + rho * accel_max
    return (v + v_rho) * 0.5 * rho + v_rho * v_rho / (2.0 * brake)


def safe_distance_opposite_direction(
    v_wrong: Any,
    v_correct: Any,
    rho: float,
    wrong_accel_max: float,
    wrong_brake_min: float,
    correct_accel_max: float,
    correct_brake_min_correct: float,
) -> np.ndarray:
    """RSS Definition 2 (m): both cars respond after ``rho``; the one in its correct lane brakes at
    ``correct_brake_min_correct``, the one in the wrong lane at ``wrong_brake_min``."""
    return _stopping(v_wrong, rho, wrong_accel_max, wrong_brake_min) + _stopping(
        v_correct, rho, correct_accel_max, correct_brake_min_correct
    )
