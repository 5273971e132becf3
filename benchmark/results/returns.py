"""Episode returns of deciders on a suite under the env's reward (``RewardConfig``).

Results files record outcomes, not returns (the reward does not change what happens); this module
measures returns with the same runner, e.g. to check that the default reward ranks the deciders
the way the task does::

    python -c "from overtakezoo.benchmark.results.returns import mean_returns; print(mean_returns())"
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from typing import Any

import numpy as np

from overtakezoo.benchmark.run.runner import run_suite
from overtakezoo.envs.config import RewardConfig
from overtakezoo.envs.suites import Suite, load_suite

DECIDERS = ("rule-fsm", "always-follow", "always-overtake", "dqn")


class _ReturnRecorder:
    """A runner recorder keeping each scenario's ``episode_return`` at the end of its chunk."""

    def __init__(self) -> None:
        self.parts: list[np.ndarray] = []

    def begin_chunk(self, core: Any, scenario_index: np.ndarray) -> None:
        pass

    def record_step(self, core: Any, modes: Any, step_result: Any) -> None:
        pass

    def end_chunk(self, core: Any) -> None:
        self.parts.append(np.asarray(core.episode_return, float).copy())


def episode_returns(
    suite: Suite | str, decider: Any, reward: RewardConfig | dict[str, Any] | None = None, limit: int | None = None
) -> np.ndarray:
    """Per-scenario returns of ``decider`` (a zoo name or a decider) on ``suite``; ``reward``
    replaces the suite's reward (a ``RewardConfig`` or a dict of its keys)."""
    suite = load_suite(suite) if isinstance(suite, str) else suite
    if reward is not None:
        if isinstance(reward, dict):
            reward = RewardConfig(**{**dataclasses.asdict(suite.config.reward), **reward})
        suite = dataclasses.replace(suite, config=dataclasses.replace(suite.config, reward=reward))
    if isinstance(decider, str):
        from overtakezoo import zoo

        decider = zoo.load(decider, config=suite.config)
    rec = _ReturnRecorder()
    run_suite(suite, decider, progress=False, recorder=rec, limit=limit)
    return np.concatenate(rec.parts)


def mean_returns(
    suite: Suite | str = "table1-train",
    deciders: Iterable[Any] = DECIDERS,
    reward: RewardConfig | dict[str, Any] | None = None,
    limit: int | None = None,
) -> dict[str, float]:
    """Mean episode return of each decider on ``suite`` (default: table1-train, the training set)."""
    suite = load_suite(suite) if isinstance(suite, str) else suite
    return {getattr(d, "name", d): float(np.mean(episode_returns(suite, d, reward, limit))) for d in deciders}
