"""Dynamics: how vehicles move under their controllers' commands.

Automated vehicles are kinematic bicycles that track the planner's path by pure pursuit, with
acceleration, jerk, steering-angle and steering-rate limits. The jerk limit is for comfort: when the
planner brakes in an emergency (``PlannerConfig.emergency_braking``), the brake is applied at once.
NPCs keep their lane and integrate their acceleration along their direction of travel.
"""

from __future__ import annotations

from typing import Any, NamedTuple

from overtakezoo.envs.model.planner import Plan, clip, lateral_profile


class AVMotion(NamedTuple):
    """The motion state of every AV row, (B,) arrays."""

    x: Any
    y: Any
    psi: Any
    v: Any
    a: Any
    steer: Any
    yaw_rate: Any


def track(m: AVMotion, p: Plan, dt: Any, pc: Any, step_dt: float, ego: dict[str, Any], xp: Any) -> tuple[AVMotion, Any]:
    """Every AV row advanced by ``dt`` (per row; zero for finished rows) along plan ``p`` under the
    planner config ``pc``; returns the new motion and the jerk each row felt (over ``step_dt``, for
    the comfort statistics)."""
    # Longitudinal: jerk-limited acceleration, speed in [0, limit].
    jerk_step = pc.max_jerk * dt
    a_new = m.a + clip(p.accel - m.a, -jerk_step, jerk_step, xp)
    if p.emergency is not None:  # an emergency brake is not smoothed
        a_new = xp.where(p.emergency & (dt > 0), xp.minimum(a_new, p.accel), a_new)
    jerk = xp.abs(a_new - m.a) / step_dt
    v_new = clip(m.v + a_new * dt, 0.0, ego["speed_limit"], xp)
    a = xp.where(v_new <= 0.0, xp.maximum(a_new, 0.0), a_new)  # at standstill the brake holds
    # Lateral: pure pursuit on the chosen rollout, steering angle and rate limited.
    lookahead = xp.maximum(pc.lookahead_gain * m.v, pc.lookahead_min)
    roll_in = pc.roll_in_speed_factor * m.v + pc.roll_in_margin
    target_y = lateral_profile(m.y, p.target_d, lookahead, ego["lane_width"], roll_in, pc.car_tip_margin, xp)
    alpha = xp.arctan2(target_y - m.y, lookahead) - m.psi
    steer_cmd = clip(xp.arctan(2.0 * pc.wheelbase * xp.sin(alpha) / lookahead), -pc.max_steer, pc.max_steer, xp)
    rate = pc.max_steer_rate * dt
    steer = m.steer + clip(steer_cmd - m.steer, -rate, rate, xp)
    yaw_rate = v_new * xp.tan(steer) / pc.wheelbase
    x = m.x + v_new * xp.cos(m.psi) * dt
    y = m.y + v_new * xp.sin(m.psi) * dt
    return AVMotion(x, y, m.psi + yaw_rate * dt, v_new, a, steer, yaw_rate), jerk


def advance_npcs(
    s: Any, v: Any, acc: Any, dt: Any, direction: Any, present: Any, crashed: Any, xp: Any
) -> tuple[Any, Any]:
    """NPC positions and speeds (M, N) after ``dt`` under ``acc``, each along its lane's
    ``direction``; absent NPCs and crashed ones (``crashed``, None when none has) stand still."""
    v = xp.maximum(v + acc * dt, 0.0) * present
    if crashed is not None:
        v = xp.where(crashed, 0.0, v)
    return s + direction * v * dt, v
