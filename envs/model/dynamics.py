"""Dynamics: how vehicles move under their controllers' commands.

Automated vehicles are kinematic bicycles that track the planner's path by pure pursuit, with
acceleration, jerk, steering-angle and steering-rate limits. The jerk limit is for comfort: when the
planner brakes in an emergency (``PlannerConfig.emergency_braking``), the brake is applied at once.
NPCs keep their lane and integrate their acceleration along their direction of travel.
"""

from __future__ import annotations

from typing import Any

from overtakezoo.envs.model.planner import Plan, clip, lateral_profile


def track(core: Any, p: Plan, dt: Any) -> Any:
    """Advance every AV row of ``core`` by ``dt`` (per row; zero for finished rows) along plan ``p``.
    Returns the jerk each row felt (for the comfort statistics)."""
    xp, pc, cfg, E = core.xp, core.cfg.planner, core.cfg, core._ego
    # Longitudinal: jerk-limited acceleration, speed in [0, limit].
    jerk_step = pc.max_jerk * dt
    a_new = core.a + clip(p.accel - core.a, -jerk_step, jerk_step, xp)
    if p.emergency is not None:  # an emergency brake is not smoothed
        a_new = xp.where(p.emergency & (dt > 0), xp.minimum(a_new, p.accel), a_new)
    jerk = xp.abs(a_new - core.a) / cfg.dt
    v_new = clip(core.v + a_new * dt, 0.0, E["speed_limit"], xp)
    core.a = xp.where(v_new <= 0.0, xp.maximum(a_new, 0.0), a_new)  # at standstill the brake holds
    # Lateral: pure pursuit on the chosen rollout, steering angle and rate limited.
    lookahead = xp.maximum(pc.lookahead_gain * core.v, pc.lookahead_min)
    roll_in = pc.roll_in_speed_factor * core.v + pc.roll_in_margin
    target_y = lateral_profile(core.y, p.target_d, lookahead, E["lane_width"], roll_in, pc.car_tip_margin, xp)
    alpha = xp.arctan2(target_y - core.y, lookahead) - core.psi
    steer_cmd = clip(xp.arctan(2.0 * pc.wheelbase * xp.sin(alpha) / lookahead), -pc.max_steer, pc.max_steer, xp)
    rate = pc.max_steer_rate * dt
    core.steer = core.steer + clip(steer_cmd - core.steer, -rate, rate, xp)
    core.yaw_rate = v_new * xp.tan(core.steer) / pc.wheelbase
    core.x = core.x + v_new * xp.cos(core.psi) * dt
    core.y = core.y + v_new * xp.sin(core.psi) * dt
    core.psi = core.psi + core.yaw_rate * dt
    core.v = v_new
    return jerk


def advance_npcs(core: Any, acc: Any, dt: Any) -> None:
    """NPCs drive along their lane under ``acc`` (M, N); crashed NPCs stand still."""
    xp, T = core.xp, core._npc
    core._npc_a = acc
    v = xp.maximum(core._npc_v + acc * dt, 0.0) * T["present"]
    if core._npc_crashed_any:
        v = xp.where(core._npc_crashed, 0.0, v)
    core._npc_v = v
    core._npc_s = core._npc_s + T["direction"] * v * dt
