"""Finite observation bounds of the env faces, derived from the observation's construction
(envs/model/observation.py, the PettingZoo NPC observation) and the config.

Every bound follows from a limit the core enforces on any scenario of the config's ``scenario``
distribution; none is fitted to data:

- ego speed in [0, speed_limit] (the core clips it); yaw rate v tan(steer) / wheelbase with
  |steer| <= ``planner.max_steer``;
- lateral offset: an episode ends off-road once the ego's side is 0.5 m beyond the road edge, and
  one step moves the ego at most ``speed_limit * dt`` (the last observation is taken after it);
- distance to the goal: the ego is at most one step past the end of the road (then the episode is
  truncated), and at most ``speed_limit * time_limit`` behind its start;
- NPC speed: IDM never accelerates past the desired speed by more than one step of
  ``npc.max_acceleration``; NPC agents (``npc_agents=True``) may accelerate at that rate for a whole
  episode;
- a perceived vehicle is within ``sensor_range`` along the road and within the road across it, so
  its ego-frame position is bounded whatever the ego's heading;
- with several automated vehicles on a road (``platoon_size``, ``oncoming_av``), every AV has the same
  Box (PettingZoo parameter sharing needs one): the farthest start from the goal (the back of the
  platoon), and the other AVs seen in the slots at up to the speed limit, anywhere across the road.

Bounds are padded outward by :data:`PAD` against float rounding. A scenario given through
``reset(options={"scenarios": ...})`` that lies outside the config's distribution (a faster lead, a
wider road, a farther goal) can exceed them; only then do the faces' clips change an observation.
"""

from __future__ import annotations

import math

import numpy as np
from gymnasium import spaces

from overtakezoo.envs.config import EnvConfig
from overtakezoo.envs.model.observation import EGO_FEATURES, SLOT_FEATURES, V2V_FEATURES, observation_size
from overtakezoo.envs.scenarios import ScenarioDistribution

PAD = 1e-4  # in feature units: float rounding of the core's arithmetic, not a modelling margin


class _Limits:
    """The physical limits the bounds are built from (metres, m/s)."""

    def __init__(self, cfg: EnvConfig, npc_agents: bool) -> None:
        d = ScenarioDistribution.from_dict(cfg.scenario)
        self.d = d
        self.v = d.speed_limit  # the ego's speed cap (its start speed is capped too)
        step = self.v * cfg.dt
        half = d.lane_width / 2
        # Off-road ends the episode when a side is 0.5 m beyond the road (core._resolve).
        self.y_lo = min(0.0, -half - 0.5 + d.ego_width / 2) - step
        self.y_hi = max(0.0, 3 * half + 0.5 - d.ego_width / 2) + step
        self.x_lo = -self.v * d.time_limit  # the ego can at most drive backwards for a whole episode
        self.x_hi = d.goal + d.road_extra + step  # truncated one step past the end of the road
        speeds = [d.lead_speed[1] + d.lead_boost[1]]
        if d.oncoming_count:
            speeds.append(d.oncoming_speed[1])
        if d.follower_count:
            speeds.append(d.follower_speed[1])
        if d.oncoming_av:
            speeds.append(d.oncoming_av_lead_speed[1])
        top = max(speeds)
        accel = cfg.npc.max_acceleration
        self.npc_v = top + accel * (d.time_limit + cfg.dt if npc_agents else cfg.dt)
        self.dy = max(self.y_hi, d.lane_width - self.y_lo)  # |NPC lane centre - ego y|
        if d.platoon_size > 1 or d.oncoming_av:
            # Several AVs on the road: an AV at the back of a platoon starts that much farther from
            # the goal; the other AVs appear in the slots at up to the speed limit, and anywhere
            # across the road (their lateral offset is bounded like this AV's own).
            self.x_lo -= (d.platoon_size - 1) * (d.platoon_gap[1] + d.ego_length)
            self.npc_v = max(self.npc_v, self.v)
            self.dy = self.y_hi - self.y_lo
        self.reach = math.hypot(d.sensor_range, self.dy)  # |ego-frame offset| of a perceived vehicle


def _box(low: list[float], high: list[float]) -> spaces.Box:
    low_a, high_a = np.asarray(low, np.float64) - PAD, np.asarray(high, np.float64) + PAD
    return spaces.Box(low_a.astype(np.float32), high_a.astype(np.float32), dtype=np.float32)


def ego_observation_space(cfg: EnvConfig, npc_agents: bool | None = None) -> spaces.Box:
    """The Box of the ego observation (layout in envs/model/observation.py) under ``cfg``."""
    lim = _Limits(cfg, cfg.npc_agents if npc_agents is None else npc_agents)
    d, oc, pc = lim.d, cfg.observation, cfg.planner
    yaw = lim.v * math.tan(pc.max_steer) / pc.wheelbase
    ego_front = d.ego_length / 2
    low = [
        0.0,
        -yaw,
        lim.y_lo / d.lane_width,
        (d.goal - lim.x_hi - ego_front) / oc.position_scale,
        d.speed_limit / oc.speed_scale,
        d.sensor_range / oc.position_scale,
    ]
    high = [
        lim.v / oc.speed_scale,
        yaw,
        lim.y_hi / d.lane_width,
        (d.goal - lim.x_lo - ego_front) / oc.position_scale,
        d.speed_limit / oc.speed_scale,
        d.sensor_range / oc.position_scale,
    ]
    flags = 3 + pc.num_rollouts + 1  # mode one-hot and blocked flags
    low += [0.0] * flags
    high += [1.0] * flags
    # One slot: presence, x, y, vx, vy in the ego frame (vx = v_npc cos - v_ego, vy = -v_npc sin).
    slot_low = [
        0.0,
        -lim.reach / oc.position_scale,
        -lim.reach / d.lane_width,
        -(lim.npc_v + lim.v) / oc.speed_scale,
        -lim.npc_v / oc.speed_scale,
    ]
    slot_high = [
        1.0,
        lim.reach / oc.position_scale,
        lim.reach / d.lane_width,
        lim.npc_v / oc.speed_scale,
        lim.npc_v / oc.speed_scale,
    ]
    slots = 2 * oc.vehicles_per_lane
    low += slot_low * slots
    high += slot_high * slots
    if oc.v2v:  # per slot: is an AV, overtaking, aborting (flags)
        low += [0.0] * (slots * V2V_FEATURES)
        high += [1.0] * (slots * V2V_FEATURES)
    if oc.time_left:  # the share of the time limit left
        low.append(0.0)
        high.append(1.0)
    width = EGO_FEATURES + flags + slots * (SLOT_FEATURES + oc.v2v * V2V_FEATURES) + oc.time_left
    assert len(low) == observation_size(cfg) == width
    return _box(low, high)


def npc_observation_space(cfg: EnvConfig, npc_s_max: float) -> spaces.Box:
    """The Box of a PettingZoo NPC agent's observation: own speed, lane, gap to the ego along its
    travel, closing speed, the ego's lateral offset from its lane, presence. ``npc_s_max`` bounds
    |an NPC's start position| in the config's distribution."""
    lim = _Limits(cfg, True)
    d, oc = lim.d, cfg.observation
    # |ego x - NPC s|: both start within their bounds and move at most their top speed for an episode.
    gap = max(lim.x_hi, -lim.x_lo) + npc_s_max + lim.npc_v * d.time_limit
    low = [
        0.0,
        0.0,
        -gap / oc.position_scale,
        -(lim.npc_v + lim.v) / oc.speed_scale,
        (lim.y_lo - d.lane_width) / d.lane_width,
        0.0,
    ]
    high = [
        lim.npc_v / oc.speed_scale,
        1.0,
        gap / oc.position_scale,
        (lim.npc_v + lim.v) / oc.speed_scale,
        lim.y_hi / d.lane_width,
        1.0,
    ]
    return _box(low, high)


def npc_start_extent(dist: ScenarioDistribution) -> float:
    """|start position| bound of every vehicle but the ego in ``dist`` (lead ahead, oncoming vehicles
    ahead, the ego's platoon then its followers behind, an oncoming AV and its lead ahead)."""
    le, length = dist.ego_length, dist.vehicle_length
    lead = dist.lead_gap[1] + (le + length) / 2
    k, f = dist.oncoming_count, dist.follower_count
    onc = le / 2 + dist.oncoming_gap[1] + max(k - 1, 0) * (dist.oncoming_headway[1] + length) + length
    platoon = (dist.platoon_size - 1) * (dist.platoon_gap[1] + le)
    fol = platoon + le / 2 + f * (dist.follower_gap[1] + length)
    oncoming_av = le + dist.oncoming_av_distance[1]
    return max(lead, onc if k else 0.0, fol if f else 0.0, platoon, oncoming_av if dist.oncoming_av else 0.0)
