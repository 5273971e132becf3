"""Outcomes: how each automated vehicle's episode ends.

An AV *crashes* on contact with any vehicle, leaves the road (*off-road*) when a side is 0.5 m
beyond it, *succeeds* when its front passes its goal back in its own lane and ahead of the vehicle
it had to pass, and *times out* at the time limit or the end of the road (truncation).
"""

from __future__ import annotations

from typing import Any

from overtakezoo.envs.ops import first_true

RUNNING, SUCCESS, CRASH, TIMEOUT, OFFROAD = 0, 1, 2, 3, 4
OUTCOME_NAMES = ("running", "success", "crash", "timeout", "offroad")


def resolve(core: Any, geo: dict[str, Any], hit: Any, active: Any) -> tuple[Any, Any]:
    """Outcomes of this step for every AV row from its contacts ``hit`` (M', B); returns
    (terminated, truncated) and updates the rows' outcome, crash partner and completion time."""
    xp, T, E = core.xp, core._sc, core._ego
    crash = active & xp.any(hit, axis=0)
    half_w = E["half_lane_width"]
    left, right = core.y + E["half_ego_width"], core.y - E["half_ego_width"]
    offroad = active & ~crash & ((right < E["offroad_low"]) | (left > E["offroad_high"]))
    front, rear = core.x + E["half_ego_length"], core.x - E["half_ego_length"]
    passed = xp.all(T["not_must_pass"] | (rear >= geo["s"] + T["half_length"]), axis=0)
    in_lane = left <= half_w
    going = active & ~crash & ~offroad
    success = going & (front >= E["goal_s"]) & in_lane & passed
    # Out of time, or out of road (a follower stuck behind the lead past the goal): truncation.
    timeout = going & ~success & ((core.t >= E["time_up"]) | (core.x > E["road_length"]))
    if crash.any():  # (which vehicle was hit matters only in a crash)
        hit_idx = xp.minimum(first_true(hit, 0, xp), max(hit.shape[0] - 1, 0))
        cols = xp.arange(core.num)
        m = core.num_npcs
        by_npc = crash & (hit_idx < m)
        core.crash_npc = xp.where(by_npc, hit_idx, core.crash_npc)
        core.crash_lane = xp.where(crash, xp.astype(T["lane"][hit_idx, cols], xp.int), core.crash_lane)
        if hit.shape[0] > m:  # other AVs in view: a contact with one names it
            core.crash_av = xp.where(crash & ~by_npc, core._other_av[xp.maximum(hit_idx - m, 0), cols], core.crash_av)
    outcome = xp.where(timeout, TIMEOUT, core.outcome)
    outcome = xp.where(success, SUCCESS, outcome)
    outcome = xp.where(offroad, OFFROAD, outcome)
    core.outcome = xp.astype(xp.where(crash, CRASH, outcome), xp.int8)
    core.stats["completion_time"] = xp.where(success, core.t, core.stats["completion_time"])
    terminated = crash | offroad | success
    core.done |= terminated | timeout
    return terminated, timeout
