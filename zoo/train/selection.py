"""Model selection on training splits: the greedy policy of a run scored on fixed training scenarios,
the best score kept. One scorer for every trainer that selects (rsl-rl ppo, the numpy ppo, dqn), so
that "the best policy seen" means the same everywhere.

The score is the success rate minus the crash rate, each training suite weighted equally. The
scenarios are the first ``per_suite`` of each training split (what the run also trains on): test
suites never enter a choice.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from overtakezoo.envs import CRASH, SUCCESS

Act = Callable[[np.ndarray, Any], np.ndarray]  # (raw observations, their config) -> modes


def selection_sets(suites: list[Any], pools: list[Any], total: int) -> list[tuple[Any, Any]]:
    """``(config, scenarios)`` per training suite: the first ``total // len(suites)`` (at least one)."""
    per_suite = max(1, int(total) // len(suites))
    return [(s.config, q.take(np.arange(min(per_suite, q.num)))) for s, q in zip(suites, pools, strict=True)]


def greedy_score(act: Act, sets: list[tuple[Any, Any]], repeat: int) -> float:
    """Success rate minus crash rate of ``act`` over ``(config, scenarios)`` sets, each set weighted
    equally (:func:`outcome_rates`)."""
    return float(np.mean([s - c for s, c in outcome_rates(act, sets, repeat)]))


def outcome_rates(act: Act, sets: list[tuple[Any, Any]], repeat: int) -> list[tuple[float, float]]:
    """(success rate, crash rate) of ``act`` on each ``(config, scenarios)`` set, every scenario run
    to its end, each decision held ``repeat`` core steps as the runner holds it. ``act`` must be
    stateless per row: finished rows are dropped once at most half the batch runs (as the benchmark
    runner does; single-AV rows never interact), which halves the cost."""
    from overtakezoo.envs import OvertakeCore
    from overtakezoo.envs.hold import hold_steps, run_to_end

    rates = []
    for config, scenarios in sets:
        live: dict[str, Any] = {"core": OvertakeCore(config), "success": 0, "crash": 0}

        def count(outcome: np.ndarray, live: dict[str, Any] = live) -> None:
            live["success"] += int((outcome == SUCCESS).sum())
            live["crash"] += int((outcome == CRASH).sum())

        def compact(obs: np.ndarray, live: dict[str, Any] = live) -> Any:
            done = np.asarray(live["core"].done)
            keep = np.flatnonzero(~done)
            if 2 * keep.size > done.size or not keep.size:
                return None
            count(live["core"].outcome[done])
            live["core"] = live["core"].clone(keep)
            return live["core"], obs[keep]

        def decide(o: np.ndarray, _: int, c: Any = config) -> np.ndarray:
            return act(o, c)

        obs = live["core"].reset(scenarios)
        run_to_end(
            live["core"],
            obs,
            decide,
            hold_steps(config.decision_interval, repeat),
            compact=compact,
        )
        count(live["core"].outcome)
        rates.append((live["success"] / scenarios.num, live["crash"] / scenarios.num))
    return rates


def decider_act(decider: Any) -> Act:
    """A stateless zoo decider (an :class:`~overtakezoo.zoo.members.learned.MLPDecider`) as ``act``."""

    def act(obs: np.ndarray, config: Any) -> np.ndarray:
        decider.config = config
        return decider.act_batch(obs)

    return act


def held_back_sets(suites: list[Any], start: int) -> list[tuple[Any, Any]]:
    """Each training suite's scenarios from ``start`` on: training data the selection never scored
    (it scores the first ones), for comparing runs on training splits only."""
    out = []
    for s in suites:
        pool = s.scenarios()
        if start >= pool.num:
            raise ValueError(f"{s.name} has {pool.num} scenarios: none is held back from {start} on")
        out.append((s.config, pool.take(np.arange(start, pool.num))))
    return out
