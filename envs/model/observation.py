"""The decider's observation: the paper's state plus what the shared planner reports.

Layout (all float32, O(1) after scaling):

- ego (6): speed, yaw rate, lateral offset / lane width, distance from the front to the goal, the
  speed limit and the sensor range (the road's scale and how far the ego can see: what a decider
  needs to read speeds and gaps relative to the road, and to know what an empty slot means);
- mode (3): one-hot of the current mode;
- planner (n + 1): 1 where the shared planner marks a rollout blocked (what OpenPlanner's own
  behaviour selector sees);
- vehicles (2 lanes x k slots x 5): for each lane (ego lane, opposite lane) the k nearest perceived
  vehicles by distance: presence flag, x, y, vx, vy relative to the ego in the ego's frame;
- v2v (2 lanes x k slots x 3, only with ``observation.v2v``): for the vehicle in the same slot, 1
  where it is an automated vehicle, and 1 where that AV is overtaking / aborting (its broadcast);
- time_left (1, only with ``observation.time_left``): the share of the time limit still left.

Only vehicles within sensor range (and their own reveal distance) appear; empty slots are zeros.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from overtakezoo.envs.config import ABORT, OVERTAKE, EnvConfig

EGO_FEATURES = 6
SLOT_FEATURES = 5
V2V_FEATURES = 3  # is an AV, overtaking, aborting
# The opt-in parts: each is an ObservationConfig flag that appends the layout part of its name.
OPTIONAL_PARTS = ("v2v", "time_left")


def observation_size(cfg: EnvConfig) -> int:
    oc = cfg.observation
    slot = SLOT_FEATURES + (V2V_FEATURES if oc.v2v else 0)
    return EGO_FEATURES + 3 + cfg.planner.num_rollouts + 1 + 2 * oc.vehicles_per_lane * slot + int(oc.time_left)


def observation_layout(cfg: EnvConfig) -> dict[str, slice]:
    """Named slices of the observation vector (used by rule deciders and docs)."""
    r = cfg.planner.num_rollouts + 1
    k = cfg.observation.vehicles_per_lane
    o = EGO_FEATURES
    end = o + 3 + r + 2 * k * SLOT_FEATURES
    layout = {
        "ego": slice(0, o),
        "mode": slice(o, o + 3),
        "blocked": slice(o + 3, o + 3 + r),
        "ego_lane": slice(o + 3 + r, o + 3 + r + k * SLOT_FEATURES),
        "opposite_lane": slice(o + 3 + r + k * SLOT_FEATURES, end),
    }
    if cfg.observation.v2v:  # the opt-in parts are appended, so every other part stays where it is
        layout["v2v"] = slice(end, end + 2 * k * V2V_FEATURES)
        end += 2 * k * V2V_FEATURES
    if cfg.observation.time_left:
        layout["time_left"] = slice(end, end + 1)
    return layout


def observe(
    cfg: EnvConfig,
    m: Any,
    mode: Any,
    blocked: Any,
    ego: dict[str, Any],
    view: dict[str, Any],
    geo: dict,
    xp: Any,
    cols: Any = None,
    view_mode: Any = None,
    t: Any = None,
) -> Any:
    """The (N, D) float32 observation of the AV rows (motion ``m``, an ``AVMotion``; ``mode``; the
    planner's last ``blocked`` flags or None) from the batch-last geometry of the vehicles in their
    ``view`` (arrays (M, N)); only the rows ``cols`` when given (auto-reset rows). ``view_mode``
    (M, N): the mode of each vehicle that is an AV, -1 for an NPC (read only with
    ``observation.v2v``; None: no AV in view); ``t`` (N,): each row's time (read only with
    ``observation.time_left``). Features are
    written through a transposed view of the C-contiguous (N, D) result (it fits in cache, so this
    beats a transpose copy)."""
    oc = cfg.observation
    sel = slice(None) if cols is None else cols
    v, psi, y = m.v[sel], m.psi[sel], m.y[sel]
    lane_width = ego["lane_width"][sel]
    lanes, dx, dy = view["lane"][:, sel], geo["dx"][:, sel], geo["dy"][:, sel]
    seen, v_along = geo["visible"][:, sel], geo["v_along"][:, sel]
    n, k = v.shape[0], oc.vehicles_per_lane
    rows_out = xp.zeros((n, observation_size(cfg)), np.float32)
    out = rows_out.T  # written feature by feature through the transposed view: no copy at the end
    out[0] = v / oc.speed_scale
    out[1] = m.yaw_rate[sel]
    out[2] = y / lane_width
    out[3] = (ego["goal_s"][sel] - m.x[sel] - ego["ego_length"][sel] / 2) / oc.position_scale
    out[4] = ego["speed_limit"][sel] / oc.speed_scale
    out[5] = ego["sensor_range"][sel] / oc.position_scale
    out[EGO_FEATURES + mode[sel], xp.arange(n)] = 1.0
    r = cfg.planner.num_rollouts + 1
    if blocked is not None:
        out[EGO_FEATURES + 3 : EGO_FEATURES + 3 + r] = blocked[sel].T
    if oc.time_left:  # (the last feature)
        limit = ego["time_limit"][sel]
        out[-1] = xp.minimum(xp.maximum((limit - t[sel]) / limit, 0.0), 1.0)

    # Slot of each vehicle: its rank by distance among the perceived vehicles of its lane (ties by
    # slot index, like a stable sort), from pairwise comparisons on (M, M, N) -- no sort, no loop.
    dist = xp.abs(dx)
    m = dist.shape[0]
    if m:
        if xp.some(view["lane_mates"][sel]):
            j = xp.arange(m)
            before = (dist[None, :] < dist[:, None]) | (
                (dist[None, :] == dist[:, None]) & (j[None, :, None] < j[:, None, None])
            )
            same_lane = view["pair_same_lane"][..., sel]  # lanes equal, the other vehicle present (cached)
            rank = xp.sum(before & seen[None, :] & same_lane, axis=1)  # (M, N)
        else:  # (at most one vehicle per lane in these rows, e.g. table1: each is first in its lane)
            rank = xp.zeros(dist.shape, xp.int)
        kept = seen & (rank < k)
        base = EGO_FEATURES + 3 + r
        if oc.v2v and view_mode is not None:
            _write_v2v(out, view_mode[:, sel], lanes, rank, kept, base + 2 * k * SLOT_FEATURES, k, xp)
        if xp.sync_free:  # every vehicle's features, masked, added into its slot: no data-dependent shape
            feats = _slot_features(xp.cos(psi), xp.sin(psi), dx, dy, v, v_along, lane_width, oc, xp)
            _add_into_slots(out, feats, lanes, rank, kept, base, k, xp)
            return rows_out
        vj, vn = xp.nonzero2(kept)
        if len(vn):
            c, s = xp.cos(psi)[vn], xp.sin(psi)[vn]
            feats = _slot_features(c, s, dx[vj, vn], dy[vj, vn], v[vn], v_along[vj, vn], lane_width[vn], oc, xp)
            row = base + (lanes[vj, vn] * k + rank[vj, vn]) * SLOT_FEATURES
            out[row[None, :] + xp.arange(SLOT_FEATURES)[:, None], vn[None, :]] = xp.astype(feats, np.float32)
    return rows_out


def _write_v2v(out: Any, view_mode: Any, lanes: Any, rank: Any, kept: Any, base: int, k: int, xp: Any) -> None:
    """Each kept vehicle's v2v features (is an AV, overtaking, aborting) into its slot of the block
    at ``base`` (the same on every backend)."""
    feats = xp.astype(xp.stack([view_mode >= 0, view_mode == OVERTAKE, view_mode == ABORT]), np.float32)
    _add_into_slots(out, feats, lanes, rank, kept, base, k, xp)


def _add_into_slots(out: Any, feats: Any, lanes: Any, rank: Any, kept: Any, base: int, k: int, xp: Any) -> None:
    """Every vehicle's (F, M, N) features ``feats``, zeroed where not ``kept``, added into its slot
    (lane, rank) of the F-wide slots from ``base``, through the transposed view ``out``: a
    scatter-add with no data-dependent shape (unkept vehicles add zeros to the last slot)."""
    f, m = feats.shape[0], kept.shape[0]
    slot = base + (lanes * k + xp.minimum(rank, k - 1)) * f  # (M, N)
    index = slot[None] + xp.arange(f)[:, None, None]
    values = xp.astype(xp.where(kept[None], feats, 0.0), np.float32)
    xp.scatter_add(out, index.reshape(f * m, -1), values.reshape(f * m, -1))


def _slot_features(c: Any, s: Any, ddx: Any, ddy: Any, vv: Any, v_along: Any, lane_width: Any, oc: Any, xp: Any) -> Any:
    """(5, ...) features of perceived vehicles: presence, position and velocity relative to the ego
    in its frame (``c``, ``s``: cos and sin of its heading; ``vv``: its speed)."""
    rvx, rvy = v_along - vv * c, -vv * s
    return xp.stack(
        [
            xp.ones_like(ddx),
            (ddx * c + ddy * s) / oc.position_scale,
            (-ddx * s + ddy * c) / lane_width,
            (rvx * c + rvy * s) / oc.speed_scale,
            (-rvx * s + rvy * c) / oc.speed_scale,
        ]
    )


INF = float("inf")
