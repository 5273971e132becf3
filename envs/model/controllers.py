"""Controllers: what sets each vehicle's acceleration.

Every vehicle of a road has one controller kind:

- ``planner``: an automated vehicle (AV). A decider picks its mode and the shared rollout planner
  (planner.py) turns the mode into a path and an acceleration, which dynamics.py tracks;
- ``idm``: a reactive human driver, the Intelligent Driver Model behind whatever occupies its lane
  ahead (other NPCs, and an AV once its reaction time has passed);
- ``scripted``: drives its scenario's speed profile, blind to the AVs (it still keeps its distance
  to the NPCs ahead of it, as a scripted OpenSCENARIO actor does);
- ``agent``: an external acceleration (an NPC exposed as an agent by the PettingZoo face).

There is one IDM (:func:`idm`, Treiber, Hennecke and Helbing 2000): the planner's speed plan and
the NPCs both call it.
"""

from __future__ import annotations

import math
from typing import Any

from overtakezoo.envs.ops import INF, NP, clip, first_argmin
from overtakezoo.envs.scenarios import SCRIPTED, SPEEDUP_WHEN_PASSED

PLANNER, IDM, SCRIPTED_KIND, AGENT = 0, 1, 2, 3
KIND_NAMES = ("planner", "idm", "scripted", "agent")


def idm(
    v: Any, v0: Any, gap: Any, lead_v: Any, a_max: Any, min_gap: Any, headway: Any, brake_term: Any, xp: Any = NP
) -> Any:
    """IDM acceleration (not clipped) at speed ``v`` towards desired speed ``v0``, ``gap`` (bumper, inf
    when nothing is ahead) behind a leader at ``lead_v``. ``brake_term`` is the caller's ``2 sqrt(a b)``
    (the planner's carries a tiny epsilon: its mode table may hold a zero acceleration)."""
    free = 1.0 - (v / xp.maximum(v0, 1e-3)) ** 4
    s_star = min_gap + xp.maximum(v * headway + v * (v - lead_v) / brake_term, 0.0)
    interaction = xp.where(xp.isfinite(gap), (s_star / xp.maximum(gap, 0.1)) ** 2, 0.0)
    return a_max * (free - interaction)


def npc_accelerations(
    s: Any,
    v: Any,
    T: dict[str, Any],
    aware: Any,
    boosted: Any,
    avs: dict[str, Any],
    dt: Any,
    npc_accel: Any,
    nc: Any,
    lane_mates: bool,
    xp: Any,
) -> tuple[Any, Any, Any, Any]:
    """(M, N) accelerations of every NPC (at ``s`` with speed ``v``, constants ``T``, under the NPC
    config ``nc``): IDM behind the nearest vehicle ahead in its lane, an NPC or an AV it has noticed
    (scripted NPCs never notice AVs); agents' accelerations where given.

    ``avs`` holds the AVs in world coordinates: ``dx`` / ``dy`` (each NPC's position minus each AV's,
    (E, M, N)), ``v_along`` (velocity along +s, (E, N)), ``half_len`` / ``half_wid`` (sums with each
    NPC's, (E, M, N) or broadcastable) and ``present`` (E, N). Returns the accelerations, the
    noticing timers ``aware`` (E, M, N) and speed-up flags ``boosted`` after ``dt``, and each NPC's
    leader among the NPCs (-1 none; None when no road has two NPCs in a lane: the collision pass
    checks each NPC against it)."""
    direction = T["direction"]
    num_roads = s.shape[-1]
    # Other NPCs ahead in the same lane, along each NPC's own direction: pairs (j, k, N).
    ahead = direction[:, None] * (s[None, :] - s[:, None])
    pair_gap = ahead - T["pair_half_len"]
    pair_gap = xp.where(T["pair_same_lane"] & (ahead > 0), pair_gap, INF)
    gap = xp.amin(pair_gap, axis=1)
    leader = first_argmin(pair_gap, 1, xp)
    lead_v = v[leader, xp.arange(num_roads)]
    npc_leader = xp.where(xp.isfinite(gap), leader, -1) if lane_mates else None
    # An AV counts once it occupies this lane ahead and the reaction delay has passed.
    dx, dy = avs["dx"], avs["dy"]  # (E, M, N): NPC minus AV, along and across the road
    half_len, half_wid = avs["half_len"], avs["half_wid"]
    av_gap = -direction * dx - half_len
    in_lane = (xp.abs(dy) < half_wid) & (av_gap > -2 * half_len)
    if dx.shape[0] > 1:  # (the single AV is always on its road while it drives)
        in_lane &= avs["present"][:, None]
    aware = xp.where(in_lane, aware + dt, 0.0)
    if xp.some(in_lane):  # (no AV in any NPC's lane: every NPC keeps its lead)
        sees = in_lane & T["notices_ego"] & (aware >= T["reaction"]) & (av_gap < gap)
        if sees.shape[0] == 1:  # one AV (the single-ego road): no choice among AVs
            gap = xp.where(sees[0], av_gap[0], gap)
            lead_v = xp.where(sees[0], direction * avs["v_along"][0], lead_v)
        else:
            seen_gap = xp.where(sees, av_gap, INF)
            nearest = first_argmin(seen_gap, 0, xp)
            closer = xp.any(sees, axis=0)
            gap = xp.where(closer, xp.amin(seen_gap, axis=0), gap)
            av_v = avs["v_along"][nearest, xp.arange(num_roads)[None, :]]
            lead_v = xp.where(closer, direction * av_v, lead_v)
    # A speed-up lead raises its desired speed once an AV draws level in the other lane.
    v_des = T["v_des"]
    if xp.some(T["speedup"]):  # (no speed-up lead in the batch: nothing to boost)
        beside = direction * dy < -half_wid  # the AV in the lane it passes through
        passing = T["speedup"] & beside & (direction * dx - half_len < nc.speedup_trigger)
        boosted = boosted | (xp.any(passing & avs["present"][:, None], axis=0) & (dt > 0))
        v_des = v_des + xp.where(boosted, T["boost"], 0.0)
    acc = idm(
        v,
        v_des,
        gap,
        lead_v,
        nc.max_acceleration,
        nc.min_gap,
        nc.time_headway,
        2.0 * math.sqrt(nc.max_acceleration * nc.comfortable_braking),
        xp,
    )
    if npc_accel is not None:
        override = xp.batch_last(npc_accel, xp.float)
        acc = xp.where(xp.isfinite(override), override, acc)
    return clip(acc, -nc.max_braking, nc.max_acceleration, xp), aware, boosted, npc_leader


def notices_avs(behaviour: Any) -> Any:
    """Which NPCs react to AVs: all but the scripted ones."""
    return behaviour != SCRIPTED


def speeds_up(behaviour: Any) -> Any:
    return behaviour == SPEEDUP_WHEN_PASSED
