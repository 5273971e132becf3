"""The decider's observation: the paper's state plus what the shared planner reports.

Layout (all float32, O(1) after scaling):

- ego (4): speed, yaw rate, lateral offset / lane width, distance from the front to the goal;
- mode (3): one-hot of the current mode;
- planner (n + 1): 1 where the shared planner marks a rollout blocked (what OpenPlanner's own
  behaviour selector sees);
- vehicles (2 lanes x k slots x 5): for each lane (ego lane, opposite lane) the k nearest perceived
  vehicles by distance: presence flag, x, y, vx, vy relative to the ego in the ego's frame.

Only vehicles within sensor range (and their own reveal distance) appear; empty slots are zeros.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .config import EnvConfig

if TYPE_CHECKING:
    from .core import OvertakeCore

EGO_FEATURES = 4
SLOT_FEATURES = 5


def observation_size(cfg: EnvConfig) -> int:
    return EGO_FEATURES + 3 + cfg.planner.num_rollouts + 1 + 2 * cfg.observation.vehicles_per_lane * SLOT_FEATURES


def observation_layout(cfg: EnvConfig) -> dict[str, slice]:
    """Named slices of the observation vector (used by rule deciders and docs)."""
    r = cfg.planner.num_rollouts + 1
    k = cfg.observation.vehicles_per_lane
    o = EGO_FEATURES
    return {"ego": slice(0, o), "mode": slice(o, o + 3), "blocked": slice(o + 3, o + 3 + r),
            "ego_lane": slice(o + 3 + r, o + 3 + r + k * SLOT_FEATURES),
            "opposite_lane": slice(o + 3 + r + k * SLOT_FEATURES, o + 3 + r + 2 * k * SLOT_FEATURES)}


def observe(core: "OvertakeCore", geo: dict[str, np.ndarray]) -> np.ndarray:
    cfg, sc = core.cfg, core.scen
    oc = cfg.observation
    n = sc.num
    k = oc.vehicles_per_lane
    goal_dist = (sc.goal_s - core.x - sc.ego_length / 2) / oc.position_scale
    ego = np.stack([core.v / oc.speed_scale, core.yaw_rate, core.y / sc.lane_width, goal_dist], axis=1)
    mode = np.zeros((n, 3))
    mode[np.arange(n), core.mode] = 1.0
    if core.last_plan is not None and core.last_plan.blocked.shape[0] == n:
        blocked = core.last_plan.blocked.astype(float)
    else:
        blocked = np.zeros((n, cfg.planner.num_rollouts + 1))

    # Relative position and velocity in the ego frame.
    c, s = np.cos(core.psi)[:, None], np.sin(core.psi)[:, None]
    dx, dy = geo["dx"], geo["dy"]
    rvx = geo["v_along"] - (core.v * np.cos(core.psi))[:, None]
    rvy = -(core.v * np.sin(core.psi))[:, None] * np.ones_like(dx)
    feats = np.stack([np.ones_like(dx), (dx * c + dy * s) / oc.position_scale,
                      (-dx * s + dy * c) / sc.lane_width[:, None],
                      (rvx * c + rvy * s) / oc.speed_scale, (-rvx * s + rvy * c) / oc.speed_scale], axis=2)
    lanes = []
    m = dx.shape[1]
    for lane in (0, 1):  # two lanes: a fixed, tiny loop, not over scenarios or vehicles
        key = np.where(geo["visible"] & (sc.npc_lane == lane), np.abs(dx), np.inf)
        order = np.argsort(key, axis=1, kind="stable")[:, :k]
        rows = np.arange(n)[:, None]
        picked = feats[rows, order]
        valid = np.isfinite(key[rows, order])[:, :, None]
        picked = np.where(valid, picked, 0.0)
        if m < k:
            picked = np.concatenate([picked, np.zeros((n, k - m, SLOT_FEATURES))], axis=1)
        lanes.append(picked.reshape(n, k * SLOT_FEATURES))
    return np.concatenate([ego, mode, blocked] + lanes, axis=1).astype(np.float32)
