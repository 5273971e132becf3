"""Reward: the same for every face and trainer (the shape and its reasons: RewardConfig)."""

from __future__ import annotations

from typing import Any


def step_reward(
    rc: Any,
    x: Any,
    outcome: Any,
    ego: dict[str, Any],
    terminated: Any,
    truncated: Any,
    switched: Any,
    active: Any,
    xp: Any,
) -> Any:
    """Per AV row (at ``x``, with ``outcome``) under the reward config ``rc``: progress towards the
    goal and a cost of time while running, a cost per switch into or out of OVERTAKE, and the
    terminal term of the outcome on the step the episode ends."""
    dist = xp.maximum(ego["goal_s"] - (x + ego["ego_length"] / 2), 0.0)
    r = (rc.progress / (1.0 + dist / rc.progress_scale) + rc.time) * active
    r = r + rc.switch * xp.astype(switched, xp.float)
    terminal = xp.asarray([0.0, rc.success, rc.crash, rc.timeout, rc.offroad], xp.float)[xp.astype(outcome, xp.int)]
    return r + terminal * (terminated | truncated)
