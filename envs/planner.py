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
5. plans speed with IDM behind the nearest same-direction vehicle on the chosen path, keeping the
   mode's following distance. ABORT merges back only where the ego lane beside the ego is clear by
   ``abort_clearance``; until then it holds its offset and drops back below the lead's speed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .config import ABORT, MODE_NAMES, OVERTAKE, PlannerConfig


def clip(x, lo, hi):
    """``np.clip`` without its Python-level dispatch (it dominates at N = 1)."""
    return np.minimum(np.maximum(x, lo), hi)


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
    def from_config(cls, cfg: PlannerConfig) -> "ModeTable":
        modes = [cfg.modes[name] for name in MODE_NAMES]
        return cls(
            velocity=np.array([m.velocity for m in modes]),
            acceleration=np.array([m.acceleration for m in modes]),
            following_distance=np.array([m.following_distance for m in modes]),
            avoiding_distance=np.array([m.avoiding_distance for m in modes]),
            rollout_number=np.array([m.rollout_number for m in modes]),
            rollout_id=np.array([m.rollout_id for m in modes]),
        )


@dataclass
class Plan:
    offsets: np.ndarray  # (N, R) rollout end offsets
    blocked: np.ndarray  # (N, R) bool
    cost: np.ndarray  # (N, R) normalized total cost (inf where not allowed)
    rollout: np.ndarray  # (N,) chosen rollout index
    target_d: np.ndarray  # (N,) the chosen path's end offset (the current offset while an abort waits)
    accel: np.ndarray  # (N,) commanded acceleration before jerk limits
    leader_gap: np.ndarray  # (N,) bumper gap to the followed vehicle (inf if none)


def lateral_profile(y: np.ndarray, target: np.ndarray, ahead: np.ndarray, lane_width: np.ndarray,
                    roll_in: np.ndarray, tip: float) -> np.ndarray:
    """Lateral offset of a rollout ``ahead`` metres down the road: the current offset ``y`` held for
    ``tip``, then a straight roll-in with the slope of a full lane change over ``roll_in`` metres,
    then the end offset. Arrays broadcast; used by the evaluator and by the tracking controller."""
    reach = lane_width / roll_in * np.maximum(ahead - tip, 0.0)
    return y + clip(target - y, -reach, reach)


def plan(cfg: PlannerConfig, table: ModeTable, mode: np.ndarray, current_rollout: np.ndarray,
         ego: dict[str, np.ndarray], npc: dict[str, np.ndarray], visible: np.ndarray) -> Plan:
    """One planning cycle for every row. ``ego``/``npc`` hold the geometry prepared by the core."""
    n = cfg.num_rollouts
    x, y, v = ego["x"], ego["y"], ego["v"]
    w = ego["lane_width"]
    dx, dj, same_dir = npc["dx"], npc["d"], npc["same_dir"]  # (N, M)
    half_len, half_wid = npc["half_len"], npc["half_wid"]  # ego + NPC half sums, (N, M)
    gap = dx - half_len  # bumper gap ego front -> NPC rear for vehicles ahead
    ahead_same = visible & same_dir & (gap > 0.0)

    k = np.arange(n + 1)
    offsets = w[:, None] * (k / n)  # (N, R)
    lat_margin = half_wid + cfg.horizontal_safety  # (N, M)

    # (a) blocked by a leader within the avoiding distance.
    avoid = table.avoiding_distance[mode]
    lat_end = np.abs(offsets[:, :, None] - dj[:, None, :])  # (N, R, M)
    inside = lat_end < lat_margin[:, None, :]
    lead_block = np.logical_or.reduce(inside & (ahead_same & (gap < avoid[:, None]))[:, None, :], axis=2)

    # (b) predicted overlap with every other perceived vehicle within the horizon.
    t = cfg.horizon_time * np.arange(cfg.horizon_samples + 1) / cfg.horizon_samples  # (T,)
    roll_in = cfg.roll_in_speed_factor * v + cfg.roll_in_margin
    d_ego = lateral_profile(y[:, None, None], offsets[:, :, None], (v[:, None] * t)[:, None, :],
                            w[:, None, None], roll_in[:, None, None], cfg.car_tip_margin)  # (N, R, T)
    rel_v = npc["v_along"] * cfg.enable_prediction - v[:, None]  # (N, M) NPC speed relative to ego
    lon = np.abs(dx[:, :, None] + rel_v[:, :, None] * t) < (half_len + cfg.vertical_safety)[:, :, None]
    watch = visible & ~ahead_same
    lon &= watch[:, :, None]  # (N, M, T)
    lat = np.abs(d_ego[:, :, None, :] - dj[:, None, :, None]) < lat_margin[:, None, :, None]  # (N,R,M,T)
    pred_block = np.logical_or.reduce(lat & lon[:, None, :, :], axis=(2, 3))
    blocked = lead_block | pred_block

    # Costs, normalized over the allowed rollouts.
    allowed = k[None, :] <= table.rollout_number[mode][:, None]
    ahead = visible & (gap > 0.0)
    priority = offsets / w[:, None]
    transition = np.abs(k[None, :] - current_rollout[:, None]) / n
    lat_cost = np.where(inside, 2.0, 1.0 / np.maximum(lat_end, 1e-3))
    lateral = np.add.reduce(np.where(ahead[:, None, :], lat_cost, 0.0), axis=2)
    longitudinal = np.add.reduce(np.where((ahead[:, None, :] & inside), 1.0 / np.maximum(gap, 1.0)[:, None, :], 0.0), axis=2)
    cost = np.zeros_like(offsets)
    for weight, term in ((cfg.weight_priority, priority), (cfg.weight_transition, transition),
                         (cfg.weight_lateral, lateral), (cfg.weight_longitudinal, longitudinal)):
        total = np.add.reduce(np.where(allowed, term, 0.0), axis=1, keepdims=True)
        cost += weight * term / np.maximum(total, 1e-9)
    cost = np.where(allowed, cost, np.inf)

    free = allowed & ~blocked
    rows = np.arange(len(mode))
    best = np.argmin(np.where(free, cost, np.inf), axis=1)
    cur_cost = cost[rows, current_rollout]
    keep = free[rows, current_rollout] & (cur_cost <= cost[rows, best] + cfg.keep_margin)
    choice = np.where(keep, current_rollout, best)
    none_free = ~np.logical_or.reduce(free, axis=1)
    fallback = np.where(mode == OVERTAKE, current_rollout, 0)
    choice = np.where(none_free, fallback, choice)
    forced = table.rollout_id[mode]
    choice = np.where(forced >= 0, forced, choice)
    target_d = offsets[rows, choice]

    # ABORT: merge back only where the ego lane beside the ego is clear; until then hold the offset
    # and drop back below the speed of the vehicle alongside (or keep going if it is behind us).
    beside = visible & same_dir & (np.abs(dx) < half_len + cfg.abort_clearance)
    waiting = (mode == ABORT) & np.logical_or.reduce(beside, axis=1)
    target_d = np.where(waiting, y, target_d)
    beside_ahead = beside & (dx > 0.0)
    lead_v = np.minimum.reduce(np.where(beside_ahead, npc["v_along"], np.inf), axis=1)
    speed_cap = np.where(waiting & np.isfinite(lead_v), np.maximum(lead_v - cfg.abort_drop_back, 0.0), np.inf)

    # Speed: IDM behind the nearest same-direction vehicle on the chosen path.
    d_path = lateral_profile(y[:, None], target_d[:, None], dx, w[:, None], roll_in[:, None], cfg.car_tip_margin)
    on_path = ahead_same & ((np.abs(d_path - dj) < half_wid) | (np.abs(y[:, None] - dj) < half_wid))
    leader_gap = np.minimum.reduce(np.where(on_path, gap, np.inf), axis=1)
    leader_idx = np.argmin(np.where(on_path, gap, np.inf), axis=1)
    leader_v = npc["v_along"][rows, leader_idx]
    v0 = np.minimum(np.minimum(table.velocity[mode], ego["speed_limit"]), speed_cap)
    a_max = table.acceleration[mode]
    free_term = 1.0 - (v / np.maximum(v0, 1e-3)) ** 4
    s_star = table.following_distance[mode] + np.maximum(
        0.0, v * cfg.time_headway + v * (v - leader_v) / (2.0 * np.sqrt(a_max * cfg.comfortable_braking) + 1e-9))
    interaction = np.where(np.isfinite(leader_gap), (s_star / np.maximum(leader_gap, 0.1)) ** 2, 0.0)
    accel = clip(a_max * (free_term - interaction), -cfg.max_braking, a_max)
    return Plan(offsets=offsets, blocked=blocked, cost=cost, rollout=choice, target_d=target_d,
                accel=accel, leader_gap=leader_gap)
