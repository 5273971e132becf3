"""The shared OpenPlanner-style rollout planner, vectorized over the batch.

Every decider drives through this planner; a decider only picks the mode (follow / overtake /
abort), and the mode selects one of three parameter sets (:class:`~.config.ModeParams`).

Per step and per scenario the planner (after OpenPlanner's ``TrajectoryEvaluator::doOneStep`` and
``PlanningHelpers::CalculateRollInTrajectories``, hatem-darweesh/common, branch openplanner.1.15):

1. samples ``n + 1`` lateral rollouts from the ego's current offset to end offsets
   ``k * lane_width / n`` (k = 0 is the ego-lane centre, k = n the opposite lane's centre): the
   current offset is held for ``car_tip_margin``, then a linear roll-in over
   ``roll_in_speed_factor * v + roll_in_margin`` metres;
2. marks a rollout *blocked* when (a) a perceived same-direction vehicle ahead lies within the
   safety width of its end offset closer than the mode's avoiding distance (OpenPlanner's
   blocked-by-leader rule), or (b) the ego driven along it at its current speed overlaps, inflated
   by the safety margins, the constant-velocity prediction of any other perceived vehicle within
   ``horizon_time`` (same-direction vehicles ahead are left to the speed planner, as OpenPlanner's
   follow behaviour does);
3. costs each rollout (priority = distance from the centre, transition = distance from the
   current rollout, lateral = 2 per vehicle inside the safety width else 1 / lateral distance,
   longitudinal = 1 / gap of vehicles on it), normalizes each cost over the allowed rollouts and
   weights them (launch default: 0.25 each);
4. picks the cheapest allowed unblocked rollout, keeping the current one when it is within
   ``keep_margin`` of the best. With every allowed rollout blocked, OVERTAKE holds its current
   rollout (it commits: aborting is the decider's call), FOLLOW and ABORT use the centre;
5. plans speed with IDM (controllers.idm) behind the nearest same-direction vehicle on the chosen
   path, keeping the mode's following distance. With ``emergency_braking`` an oncoming vehicle on
   the path counts too, as a standing obstacle where the two would meet, and braking beyond the
   comfortable deceleration skips the jerk limit (dynamics.py). ABORT merges back only where the ego
   lane beside the ego is clear by ``abort_clearance``; until then it holds its offset and drops
   back below the lead's speed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from overtakezoo.envs.backend import Array
from overtakezoo.envs.config import ABORT, MODE_NAMES, OVERTAKE, PlannerConfig
from overtakezoo.envs.model.controllers import idm
from overtakezoo.envs.ops import INF, NP, clip, first_argmin


@dataclass
class ModeTable:
    """The three parameter sets as arrays indexed by mode, for gathering per row."""

    velocity: np.ndarray
    acceleration: np.ndarray
    following_distance: np.ndarray
    avoiding_distance: np.ndarray
    rollout_number: np.ndarray
    rollout_id: np.ndarray

    @classmethod
    def from_config(cls, cfg: PlannerConfig) -> ModeTable:
        modes = [cfg.modes[name] for name in MODE_NAMES]
        return cls(
            velocity=np.array([m.velocity for m in modes]),
            acceleration=np.array([m.acceleration for m in modes]),
            following_distance=np.array([m.following_distance for m in modes]),
            avoiding_distance=np.array([m.avoiding_distance for m in modes]),
            rollout_number=np.array([m.rollout_number for m in modes]),
            rollout_id=np.array([m.rollout_id for m in modes]),
        )

    def to(self, xp) -> ModeTable:
        """The same table as arrays of backend ``xp``."""
        return ModeTable(**{k: xp.asarray(v) for k, v in self.__dict__.items()})


@dataclass
class Plan:
    offsets: np.ndarray  # (N, R) rollout end offsets
    blocked: np.ndarray  # (N, R) bool
    cost: np.ndarray  # (N, R) normalized total cost (inf where not allowed)
    rollout: np.ndarray  # (N,) chosen rollout index
    target_d: np.ndarray  # (N,) the chosen path's end offset (the current offset while an abort waits)
    accel: np.ndarray  # (N,) commanded acceleration before jerk limits
    leader_gap: np.ndarray  # (N,) bumper gap to the followed vehicle (inf if none)
    emergency: np.ndarray | None = None  # (N,) bool: braking beyond comfort (emergency_braking only)


def lateral_profile(
    y: np.ndarray, target: np.ndarray, ahead: np.ndarray, lane_width: np.ndarray, roll_in: np.ndarray, tip: float, xp=NP
) -> np.ndarray:
    """Lateral offset of a rollout ``ahead`` metres down the road: the current offset ``y`` held for
    ``tip``, then a straight roll-in with the slope of a full lane change over ``roll_in`` metres,
    then the end offset. Arrays broadcast; used by the evaluator and by the tracking controller."""
    reach = lane_width / roll_in * xp.maximum(ahead - tip, 0.0)
    return y + clip(target - y, -reach, reach, xp)


def _swept_conflict(y, v, offsets, dj, margin, lane_width, roll_in, tip, t_from, t_to, xp):
    """(R, M, N) bool: does the ego, driven at speed ``v`` along each rollout's lateral profile (see
    :func:`lateral_profile`), come within ``margin`` of lateral position ``dj`` at some time in
    [t_from, t_to] (M, N)? Sideways progress is monotone in time, so the window maps to a progress
    interval [p_from, p_to] on each rollout; the test is its overlap with the vehicle's band."""
    delta = offsets - y  # (R, N) lateral travel to each end offset
    sign = xp.where(delta >= 0.0, 1.0, -1.0)
    span = xp.abs(delta)[:, None, :]
    lat_speed = lane_width * v / roll_in  # (N,) m/s sideways once the roll-in starts (after the tip)
    moving = lat_speed > 1e-9
    t_start = tip / xp.where(moving, v, 1.0)
    rate = xp.where(moving, lat_speed, 1.0)  # (a placeholder where standing: avoids inf * 0)
    # Unclipped progress at the window's ends (M, N); a standing ego makes no progress.
    u_from = xp.where(moving, (t_from - t_start) * rate, 0.0)
    u_to = xp.where(moving, (t_to - t_start) * rate, 0.0)
    p_from = xp.minimum(xp.maximum(u_from, 0.0), span)  # (R, M, N)
    p_to = xp.minimum(xp.maximum(u_to, 0.0), span)
    # In each rollout's signed frame the ego moves towards +p; the vehicle's band is rel +- margin.
    rel = (dj - y)[None, :, :] * sign[:, None, :]
    return (p_to > rel - margin) & (p_from < rel + margin)


def _longitudinal_window(dx, rel_v, reach, xp):
    """Times [t0, t1] (M, N) during which |dx + rel_v t| < reach (constant relative speed)."""
    still = xp.abs(rel_v) < 1e-9
    if not xp.some(still):  # (every vehicle moves relative to the ego: no special case to mask)
        a, b = (-reach - dx) / rel_v, (reach - dx) / rel_v
        return xp.minimum(a, b), xp.maximum(a, b)
    safe_v = xp.where(still, 1.0, rel_v)
    a, b = (-reach - dx) / safe_v, (reach - dx) / safe_v
    inside_now = xp.abs(dx) < reach
    t0 = xp.where(still, xp.where(inside_now, -INF, INF), xp.minimum(a, b))
    t1 = xp.where(still, xp.where(inside_now, INF, -INF), xp.maximum(a, b))
    return t0, t1


def rollout_geometry(
    cfg: PlannerConfig, lane_width: np.ndarray, d: np.ndarray, half_wid: np.ndarray, half_len: np.ndarray, xp=NP
) -> dict:
    """What the evaluator needs that is fixed for an episode (NPCs keep their lanes): rollout end
    offsets (R, N) and their priority, per vehicle (M, N) the longitudinal reach of the prediction
    and of the abort's clearance, and, per rollout and vehicle (R, M, N), the lateral distance,
    whether it is inside the safety width, and its lateral cost. The core caches this at reset."""
    k = xp.arange(cfg.num_rollouts + 1)[:, None]
    offsets = (k / cfg.num_rollouts) * lane_width
    lat_margin = half_wid + cfg.horizontal_safety
    lat_end = xp.abs(offsets[:, None, :] - d)
    inside = lat_end < lat_margin
    return {
        "offsets": offsets,
        "lat_margin": lat_margin,
        "lat_end": lat_end,
        "inside": inside,
        "lat_cost": xp.where(inside, 2.0, 1.0 / xp.maximum(lat_end, 1e-3)),
        "priority": offsets / lane_width,
        "lon_reach": half_len + cfg.vertical_safety,
        "beside_reach": half_len + cfg.abort_clearance,
    }


def plan(
    cfg: PlannerConfig,
    table: ModeTable,
    mode: np.ndarray,
    current_rollout: np.ndarray,
    ego: dict[str, np.ndarray],
    npc: dict[str, np.ndarray],
    xp=NP,
) -> Plan:
    """One planning cycle for every row. ``ego`` holds (N,) arrays; ``npc`` the core's geometry in
    batch-last layout, (M, N). Internal arrays are (R, N) and (R, M, N): the batch is the
    contiguous axis, so reductions over rollouts and vehicles are fast elementwise passes."""
    n = cfg.num_rollouts
    y, v, w = ego["y"], ego["v"], ego["lane_width"]
    cols = xp.arange(len(mode))
    dx, dj, same_dir, visible = npc["dx"], npc["d"], npc["same_dir"], npc["visible"]  # (M, N)
    half_len, half_wid = npc["half_len"], npc["half_wid"]  # ego + NPC half sums
    gap = dx - half_len  # bumper gap ego front -> NPC rear for vehicles ahead
    ahead_same = visible & same_dir & (gap > 0.0)

    k = xp.arange(n + 1)[:, None]  # (R, 1)
    offsets, lat_margin, inside = npc["offsets"], npc["lat_margin"], npc["inside"]  # see rollout_geometry

    # (a) blocked by a leader within the avoiding distance.
    avoid = table.avoiding_distance[mode]
    lead_block = xp.any(inside & (ahead_same & (gap < avoid)), axis=1)

    # (b) predicted overlap with every other perceived vehicle within the horizon, solved in closed
    # form: the longitudinal overlap is one time interval, during which the ego sweeps one lateral
    # interval per rollout; a conflict is that sweep touching the vehicle (exact in continuous time,
    # and O(R M N), not O(R M N T)).
    roll_in = cfg.roll_in_speed_factor * v + cfg.roll_in_margin
    blocked = lead_block  # (R, N)
    watch = visible & ~ahead_same
    if xp.some(watch):  # (no other perceived vehicle: nothing to predict)
        rel_v = npc["v_along"] * cfg.enable_prediction - v  # (M, N) NPC speed relative to the ego
        lon_t0, lon_t1 = _longitudinal_window(dx, rel_v, npc["lon_reach"], xp)
        t_from, t_to = xp.maximum(lon_t0, 0.0), xp.minimum(lon_t1, cfg.horizon_time)
        watch = watch & (t_from <= t_to)  # (M, N): longitudinally in reach in the horizon
        if xp.some(watch):
            swept = _swept_conflict(y, v, offsets, dj, lat_margin, w, roll_in, cfg.car_tip_margin, t_from, t_to, xp)
            blocked = lead_block | xp.any(swept & watch, axis=1)

    # Costs, normalized over the allowed rollouts.
    allowed = k <= table.rollout_number[mode]  # (R, N)
    ahead = visible & (gap > 0.0)
    priority = npc["priority"]
    transition = xp.abs(k - current_rollout) / n
    lateral = xp.sum(xp.where(ahead, npc["lat_cost"], 0.0), axis=1)
    longitudinal = xp.sum(xp.where(ahead & inside, 1.0 / xp.maximum(gap, 1.0), 0.0), axis=1)
    everywhere = not xp.some(~allowed)  # (every rollout allowed in every row, e.g. all overtaking: nothing to mask)
    cost: Array = 0.0  # (R, N) once the first term is added
    for weight, term in (
        (cfg.weight_priority, priority),
        (cfg.weight_transition, transition),
        (cfg.weight_lateral, lateral),
        (cfg.weight_longitudinal, longitudinal),
    ):
        total = xp.sum(term if everywhere else xp.where(allowed, term, 0.0), axis=0)
        cost += weight * term / xp.maximum(total, 1e-9)
    if not everywhere:
        cost = xp.where(allowed, cost, INF)

    free = allowed & ~blocked
    free_cost = xp.where(free, cost, INF)
    best = first_argmin(free_cost, xp=xp)
    keep = free[current_rollout, cols] & (cost[current_rollout, cols] <= free_cost[best, cols] + cfg.keep_margin)
    choice = xp.where(keep, current_rollout, best)
    none_free = ~xp.any(free, axis=0)
    if xp.some(none_free):  # (some row has every allowed rollout blocked)
        fallback = xp.where(mode == OVERTAKE, current_rollout, 0)
        choice = xp.where(none_free, fallback, choice)
    forced = table.rollout_id[mode]
    choice = xp.where(forced >= 0, forced, choice)
    target_d = offsets[choice, cols]

    # ABORT: merge back only where the ego lane beside the ego is clear; until then hold the offset
    # and drop back below the speed of the vehicle alongside (or keep going if it is behind us).
    v0 = xp.minimum(table.velocity[mode], ego["speed_limit"])
    aborting = mode == ABORT
    if xp.some(aborting):  # (no row aborting: no speed cap, the target stands)
        beside = visible & same_dir & (xp.abs(dx) < npc["beside_reach"])
        waiting = aborting & xp.any(beside, axis=0)
        target_d = xp.where(waiting, y, target_d)
        lead_v = xp.amin(xp.where(beside & (dx > 0.0), npc["v_along"], INF), axis=0)
        speed_cap = xp.where(waiting & xp.isfinite(lead_v), xp.maximum(lead_v - cfg.abort_drop_back, 0.0), INF)
        v0 = xp.minimum(v0, speed_cap)

    # Speed: IDM behind the nearest same-direction vehicle on the chosen path.
    # The path's offset where the ego would draw level with the vehicle's front: the closest it gets.
    d_path = lateral_profile(y, target_d, dx + half_len, w, roll_in, cfg.car_tip_margin, xp)  # (M, N)
    # A same-direction vehicle whose centre is ahead counts even while alongside (negative gap): a path
    # that turns into it makes the ego brake hard and fall in behind, as OpenPlanner's follow does.
    on_path = visible & same_dir & (dx > 0.0) & ((xp.abs(d_path - dj) < half_wid) | (xp.abs(y - dj) < half_wid))
    path_gap = xp.where(on_path, gap, INF)
    head_on = None
    if cfg.emergency_braking:  # (off: like OpenPlanner's follow, only same-direction vehicles are followed)
        # An oncoming vehicle on the path: stop short of where the two would meet at today's speeds.
        near = (xp.abs(d_path - dj) < half_wid) | (xp.abs(y - dj) < half_wid)
        head_on = visible & ~same_dir & (dx > 0.0) & near
        meet = gap * v / xp.maximum(v - npc["v_along"], 1e-3)
        head_on = head_on & (meet < path_gap)
        path_gap = xp.where(head_on, meet, path_gap)
    leader_gap = xp.amin(path_gap, axis=0)
    leader = first_argmin(path_gap, xp=xp)
    leader_v = npc["v_along"][leader, cols]
    if head_on is not None:
        leader_v = xp.where(head_on[leader, cols], 0.0, leader_v)  # the meeting point does not move
    a_max = table.acceleration[mode]
    accel = clip(
        idm(
            v,
            v0,
            leader_gap,
            leader_v,
            a_max,
            table.following_distance[mode],
            cfg.time_headway,
            2.0 * xp.sqrt(a_max * cfg.comfortable_braking) + 1e-9,
            xp,
        ),
        -cfg.max_braking,
        a_max,
        xp,
    )
    emergency = (accel < -cfg.comfortable_braking) if cfg.emergency_braking else None
    # Plan fields are (N, R) views, batch first like every public array.
    return Plan(
        offsets=offsets.T,
        blocked=blocked.T,
        cost=cost.T,
        rollout=choice,
        target_d=target_d,
        accel=accel,
        leader_gap=leader_gap,
        emergency=emergency,
    )
