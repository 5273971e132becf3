"""Outcomes: how each automated vehicle's episode ends.

An AV *crashes* on contact with any vehicle, leaves the road (*off-road*) when a side is 0.5 m
beyond it, *succeeds* when its front passes its goal back in its own lane and ahead of the vehicle
it had to pass, and *times out* at the time limit or the end of the road (truncation).
"""

from __future__ import annotations

from typing import Any, NamedTuple

from overtakezoo.envs.ops import first_true

RUNNING, SUCCESS, CRASH, TIMEOUT, OFFROAD = 0, 1, 2, 3, 4
OUTCOME_NAMES = ("running", "success", "crash", "timeout", "offroad")


class Ending(NamedTuple):
    """How each AV row's episode stands, (B,) arrays: outcome, crash partner (NPC slot, its lane,
    the other AV), completion time and done."""

    outcome: Any
    crash_npc: Any
    crash_lane: Any
    crash_av: Any
    completion_time: Any
    done: Any


def resolve(
    x: Any,
    y: Any,
    t: Any,
    prev: Ending,
    ego: dict[str, Any],
    view: dict[str, Any],
    geo: dict[str, Any],
    hit: Any,
    active: Any,
    num_npcs: int,
    others: Any,
    xp: Any,
) -> tuple[Any, Any, Ending]:
    """Outcomes of this step for every AV row (position ``x``, ``y`` at time ``t``) from its
    contacts ``hit`` (M', B) with the vehicles of its ``view`` (the NPCs, then the AVs ``others``
    (E - 1, B) names: None on a single-AV road); returns (terminated, truncated, the new :class:`Ending`)."""
    crash = active & xp.any(hit, axis=0)
    half_w = ego["half_lane_width"]
    left, right = y + ego["half_ego_width"], y - ego["half_ego_width"]
    offroad = active & ~crash & ((right < ego["offroad_low"]) | (left > ego["offroad_high"]))
    front, rear = x + ego["half_ego_length"], x - ego["half_ego_length"]
    passed = xp.all(view["not_must_pass"] | (rear >= geo["s"] + view["half_length"]), axis=0)
    in_lane = left <= half_w
    going = active & ~crash & ~offroad
    success = going & (front >= ego["goal_s"]) & in_lane & passed
    # Out of time, or out of road (a follower stuck behind the lead past the goal): truncation.
    timeout = going & ~success & ((t >= ego["time_up"]) | (x > ego["road_length"]))
    crash_npc, crash_lane, crash_av = prev.crash_npc, prev.crash_lane, prev.crash_av
    if xp.some(crash):  # (which vehicle was hit matters only in a crash)
        hit_idx = xp.minimum(first_true(hit, 0, xp), max(hit.shape[0] - 1, 0))
        cols = xp.arange(x.shape[0])
        by_npc = crash & (hit_idx < num_npcs)
        crash_npc = xp.where(by_npc, hit_idx, crash_npc)
        crash_lane = xp.where(crash, xp.astype(view["lane"][hit_idx, cols], xp.int), crash_lane)
        if hit.shape[0] > num_npcs:  # other AVs in view: a contact with one names it
            crash_av = xp.where(crash & ~by_npc, others[xp.maximum(hit_idx - num_npcs, 0), cols], crash_av)
    outcome = xp.where(timeout, TIMEOUT, prev.outcome)
    outcome = xp.where(success, SUCCESS, outcome)
    outcome = xp.where(offroad, OFFROAD, outcome)
    outcome = xp.astype(xp.where(crash, CRASH, outcome), xp.int8)
    completion_time = xp.where(success, t, prev.completion_time)
    terminated = crash | offroad | success
    return (
        terminated,
        timeout,
        Ending(outcome, crash_npc, crash_lane, crash_av, completion_time, prev.done | terminated | timeout),
    )
