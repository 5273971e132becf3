"""Frames on a road with several automated vehicles (AVs): every AV drives in its own frame.

AV ``e`` of road ``n`` is row ``e * N + n`` (AV-major). An AV driving towards -s sees the road
mirrored: its +s is the world's -s and its lane 0 is the world's lane 1. Each AV row's view holds
the road's NPCs and then the other AVs of its road, batch-last ``(M', B)`` arrays as on a
single-AV road. Pure functions of the core's arrays; ``xp`` is the array backend.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from overtakezoo.envs.model.outcomes import CRASH
from overtakezoo.envs.model.planner import rollout_geometry
from overtakezoo.envs.scenarios import OPPOSITE_LANE

INF = float("inf")


def other_avs(num_rows: int, num_roads: int, num_avs: int, xp: Any) -> Any:
    """(E - 1, B): for each AV row, the index of each other AV of its road, in order."""
    mine = xp.arange(num_rows) // num_roads
    k = xp.arange(num_avs - 1)[:, None]
    return k + (k >= mine[None, :])


def av_constants(sc: Any, xp: Any) -> dict[str, Any]:
    """Per AV row: direction, goal and road end in its own frame, and its lead."""
    n = sc.num
    direction = np.concatenate([np.ones(n), sc.av_direction.T.reshape(-1).astype(float)])
    goal = np.concatenate([sc.goal_s, (sc.av_goal_s * sc.av_direction).T.reshape(-1)])
    beyond = np.concatenate([sc.road_length] * sc.num_avs) - np.concatenate([sc.goal_s] * sc.num_avs)
    lead = np.concatenate([np.full(n, -1), sc.av_lead.T.reshape(-1).astype(int)])
    return {
        "direction": xp.asarray(direction, xp.float),
        "goal_s": xp.asarray(goal, xp.float),
        "road_length": xp.asarray(goal + beyond, xp.float),
        "lead": xp.asarray(lead, xp.int),
    }


def view_terms(V: dict[str, Any], ego: dict[str, Any], planner: Any, xp: Any) -> dict[str, Any]:
    """What the planner, the outcomes and the observation need of the vehicles an AV row sees,
    from their ``lane``, ``d``, sizes and flags (all (M', B))."""
    out = {
        "half_len": (ego["ego_length"] + V["length"]) / 2,
        "half_wid": (ego["ego_width"] + V["width"]) / 2,
        "reach": xp.minimum(ego["sensor_range"], V["reveal"]),
        "not_must_pass": ~V["must_pass"],
    }
    out.update(rollout_geometry(planner, ego["lane_width"], V["d"], out["half_wid"], out["half_len"], xp))
    return out


def view_constants(T: dict[str, Any], ego: dict[str, Any], num_avs: int, xp: Any) -> dict[str, Any]:
    """The NPCs as each AV row sees them (M, B), mirrored for AVs driving towards -s."""
    tile = lambda a: xp.concatenate([a] * num_avs, axis=-1)  # noqa: E731  (M, N) -> (M, B), AV-major
    flip = ego["direction"] < 0
    lane = xp.where(flip, 1 - tile(T["lane"]), tile(T["lane"]))
    slot = xp.arange(T["lane"].shape[0])[:, None]
    must_pass = xp.where(ego["lead"] >= 0, slot == ego["lead"], tile(T["must_pass"]))
    return {
        "lane": lane,
        "d": lane * ego["lane_width"],
        "same_dir": lane != OPPOSITE_LANE,
        "length": tile(T["length"]),
        "width": tile(T["width"]),
        "present": tile(T["present"]),
        "reveal": tile(T["reveal"]),
        "must_pass": must_pass,
        "psi": xp.zeros(lane.shape),
    }


def av_velocity(v: Any, psi: Any, done: Any, direction: Any, num_avs: int, xp: Any) -> Any:
    """(E, N): each AV's velocity along +s (zero once it is done: it has stopped or left)."""
    return (direction * v * xp.cos(psi) * ~done).reshape(num_avs, -1)


def avs_world(
    x: Any, y: Any, psi: Any, v: Any, done: Any, outcome: Any, ego: dict[str, Any], num_avs: int, xp: Any
) -> dict[str, Any]:
    """The AVs in world coordinates, (E, N) arrays (for the NPCs' controllers and the views)."""
    e, direction = num_avs, ego["direction"]
    present = ~(done & (outcome != CRASH))  # a crashed AV stays where it stopped
    return {
        "s": (direction * x).reshape(e, -1),
        "d": xp.where(direction > 0, y, ego["lane_width"] - y).reshape(e, -1),
        "psi": psi.reshape(e, -1),
        "v_along": av_velocity(v, psi, done, direction, e, xp),
        "present": present.reshape(e, -1),
    }


def multi_geometry(
    avs: dict[str, Any],
    x: Any,
    y: Any,
    npc_s: Any,
    npc_v: Any,
    npc: dict[str, Any],
    npc_view: dict[str, Any],
    ego: dict[str, Any],
    num_avs: int,
    planner: Any,
    xp: Any,
) -> tuple[dict[str, Any], dict[str, Any]]:
    """The geometry of every vehicle each AV row sees (the NPCs, then the other AVs, mirrored into
    its frame), and the view's terms ``V``. The other AVs move sideways, so their view terms are
    rebuilt every step."""
    e, direction, w = num_avs, ego["direction"], ego["lane_width"]
    n = npc_s.shape[-1]
    tile = lambda a: xp.concatenate([a] * e, axis=-1)  # noqa: E731
    others = other_avs(x.shape[0], n, e, xp)  # (E - 1, B): the AV index each column of an AV row's view holds
    cols = xp.arange(x.shape[0])[None, :] % n
    o_s, o_d = avs["s"][others, cols], avs["d"][others, cols]
    o_dir = direction.reshape(e, n)[others, cols]
    V = dict(npc_view)
    av_lane = xp.astype(xp.where(direction > 0, o_d, w - o_d) > w / 2, xp.int)
    av_part = {
        "lane": av_lane,
        "d": xp.where(direction > 0, o_d, w - o_d),
        "same_dir": o_dir == direction,
        "length": ego["ego_length"] + 0 * o_s,
        "width": ego["ego_width"] + 0 * o_s,
        "present": avs["present"][others, cols],
        "reveal": xp.full(o_s.shape, INF),
        "must_pass": xp.zeros(o_s.shape, xp.bool),
        "psi": avs["psi"][others, cols],
    }
    V = {k: xp.concatenate([V[k], av_part[k]]) for k in V}
    V.update(view_terms(V, ego, planner, xp))
    V["half_length"], V["half_width"] = V["length"] / 2, V["width"] / 2
    m = V["lane"].shape[0]
    V["pair_same_lane"] = (V["lane"][:, None] == V["lane"][None, :]) & V["present"][None, :]
    mates = xp.arange(m)[:, None] != xp.arange(m)[None, :]
    V["lane_mates"] = xp.any(xp.any(V["pair_same_lane"] & mates[:, :, None], axis=0), axis=0)
    V["direction"] = xp.where(V["same_dir"], 1.0, -1.0)
    s = xp.concatenate([tile(npc_s) * direction, direction * o_s])
    v_along = xp.concatenate([tile(npc["direction"] * npc_v) * direction, direction * avs["v_along"][others, cols]])
    dx = s - x
    geo = {
        "s": s,
        "dx": dx,
        "dy": V["d"] - y,
        "d": V["d"],
        "same_dir": V["same_dir"],
        "direction": V["direction"],
        "v_along": v_along,
        "half_len": V["half_len"],
        "half_wid": V["half_wid"],
        "visible": V["present"] & (xp.abs(dx) <= V["reach"]),
        "psi": V["psi"],
    }
    return geo, V
