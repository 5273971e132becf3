"""Reward: the same for every face and trainer (the shape and its reasons: RewardConfig)."""

from __future__ import annotations

from typing import Any


def step_reward(core: Any, terminated: Any, truncated: Any, switched: Any, active: Any) -> Any:
    """Per AV row: progress towards the goal and a cost of time while running, a cost per switch into
    or out of OVERTAKE, and the terminal term of the outcome on the step the episode ends."""
    xp, rc, E = core.xp, core.cfg.reward, core._ego
    dist = xp.maximum(E["goal_s"] - (core.x + E["ego_length"] / 2), 0.0)
    r = (rc.progress / (1.0 + dist / rc.progress_scale) + rc.time) * active
    r = r + rc.switch * xp.astype(switched, xp.float)
    terminal = xp.asarray([0.0, rc.success, rc.crash, rc.timeout, rc.offroad], xp.float)[xp.astype(core.outcome, xp.int)]
    return r + terminal * (terminated | truncated)
