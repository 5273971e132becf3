"""What the learned members (dqn, double-dqn, ppo) share: verified weights, model cards,
hyperparameter files (which never change the env's reward), and the results a model card quotes (measured with the benchmark runner)."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from overtakezoo.envs import CRASH, SUCCESS, TIMEOUT


def read_hyperparams(path: str | Path, required: set[str]) -> dict[str, Any]:
    """A hyperparameter file (TOML) with its ``required`` top-level keys; ``hp["file"]`` is its name."""
    path = Path(path)
    try:
        hp = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"hyperparameter file {path} not found") from None
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ValueError(f"hyperparameter file {path}: {exc}") from None
    missing = required - set(hp)
    if missing:
        raise ValueError(f"hyperparameter file {path}: missing keys {', '.join(sorted(missing))}")
    reject_reward_keys(hp, f"hyperparameter file {path}")
    hp["file"] = path.name
    return hp


def reject_reward_keys(hp: dict[str, Any], where: str) -> None:
    """Every trainer learns from the env's reward (``RewardConfig``, set in a suite's ``[sim.reward]``
    table): a hyperparameter that would change it for training only is refused, not ignored."""
    for key in ("reward", "time_penalty"):
        if key in hp:
            raise ValueError(f"{where}: {key!r} is not a training setting: every trainer uses the env's reward "
                             "(RewardConfig); change it in the suite's [sim.reward] table")


def outcome_summary(outcome: np.ndarray, crash_lane: np.ndarray, completion_time: np.ndarray) -> dict[str, Any]:
    """The results block of a model card, with 95 % Wilson intervals."""
    from overtakezoo.benchmark.metrics import wilson

    n = len(outcome)
    succ, crash, tout = (int((outcome == k).sum()) for k in (SUCCESS, CRASH, TIMEOUT))
    return {
        "count": n, "success": succ, "crash": crash, "timeout": tout, "offroad": n - succ - crash - tout,
        "success_rate": succ / n, "success_ci": list(wilson(succ, n)),
        "crash_rate": crash / n, "crash_ci": list(wilson(crash, n)), "timeout_rate": tout / n,
        # Lane 0 is the ego's lane (the lead, NPC1, in table1); lane 1 the opposite lane.
        "crash_lead_lane": int(((outcome == CRASH) & (crash_lane == 0)).sum()),
        "crash_opposite_lane": int(((outcome == CRASH) & (crash_lane == 1)).sum()),
        "mean_completion_time_s": float(np.nanmean(completion_time)) if succ else None,
    }


def evaluate(decider: Any, suite: Any, progress: bool = False, limit: int | None = None) -> tuple[dict[str, Any], Any]:
    """Run ``decider`` on ``suite`` (a name, path or Suite) with the benchmark runner: the card's
    summary and the full Results."""
    from overtakezoo.benchmark.runner import run_suite
    from overtakezoo.envs.suites import load_suite

    suite = load_suite(suite) if isinstance(suite, (str, Path)) else suite
    res = run_suite(suite, decider, progress=progress, limit=limit)
    summary = outcome_summary(np.asarray(res.per["outcome"]), np.asarray(res.per["crash_lane"]),
                              np.asarray(res.per["completion_time"], float))
    summary["suite"] = {"name": suite.name, "version": suite.version, "sha256": suite.hash,
                        "measured_with": "overtakezoo.benchmark.runner.run_suite"}
    return summary, res
