"""Run a decider on a suite: the whole suite as one batch (in chunks to bound memory).

The runner applies the action hold (``overtakezoo.envs.hold``): the decider acts on the batch's
observations, and each decision is held for ``hold_steps(decision_interval, decider.action_repeat)``
core steps; finished rows are frozen by the core, so the loop simply steps until every row is done.
"""

from __future__ import annotations

import math
import sys
import time
from datetime import datetime, timezone
from typing import Any

import numpy as np
from tqdm import tqdm

from overtakezoo.envs import OvertakeCore
from overtakezoo.envs.hold import hold, hold_steps

from .results import PER_SCENARIO, Results, round_per_scenario
from .errors import UserError
from .suites import Suite, shard_bounds


def run_suite(suite: Suite, decider: Any, shard: tuple[int, int] | None = None, chunk_size: int = 4096,
              progress: bool = True, recorder: Any = None, limit: int | None = None) -> Results:
    """Evaluate ``decider`` on ``suite`` (or its shard ``(i, k)``, 0-based) and return the results.

    ``recorder`` (optional) gets ``begin_chunk(core, scenario_index)``, ``record_step(core, modes,
    step_result)`` after every step and ``end_chunk(core)``; its creator closes it. ``limit`` keeps
    only the first ``limit`` scenarios of the (shard's) range.
    """
    start, stop = shard_bounds(suite.count, shard)
    scenarios = suite.scenarios(shard)
    _single_av(suite, scenarios)
    if limit is not None:
        stop = min(stop, start + limit)
        scenarios = scenarios.take(slice(0, stop - start))
    t0, started = time.perf_counter(), datetime.now(timezone.utc)
    per, total_steps = _run(suite, decider, scenarios, np.arange(start, stop), chunk_size, progress, recorder)
    timing = {"wall_time_s": round(time.perf_counter() - t0, 3),
              "started": started.isoformat(timespec="seconds"), "steps": total_steps}
    return Results.create(suite, decider, per, start=start, stop=stop, shard=shard, timing=timing)


def run_indices(suite: Suite, decider: Any, indices: np.ndarray, chunk_size: int = 4096) -> dict[str, np.ndarray]:
    """Per-scenario arrays (rounded as results files store them) for the suite's scenarios ``indices``.

    The whole suite is drawn and the rows taken, and rows never interact, so each value equals the
    same scenario's value in a full run (what ``leaderboard --verify`` relies on)."""
    indices = np.asarray(indices, dtype=np.int64)
    if indices.size and not (0 <= indices.min() and indices.max() < suite.count):
        raise ValueError(f"scenario indices must lie in [0, {suite.count})")
    scenarios = suite.scenarios().take(indices)
    _single_av(suite, scenarios)
    return _run(suite, decider, scenarios, indices, chunk_size, False, None)[0]


def _single_av(suite: Suite, scenarios: Any) -> None:
    """Results files hold one row per scenario, one AV's outcome: refuse multi-AV suites clearly."""
    if scenarios.num_avs > 1:
        raise UserError(f"suite {suite.name!r} has {scenarios.num_avs} automated vehicles per scenario; results "
                        "files hold one (per-AV results are not written yet: scripts/multi_rates.py prints "
                        "their outcome rates)")


def _run(suite: Suite, decider: Any, scenarios: Any, index: np.ndarray, chunk_size: int, progress: bool,
         recorder: Any) -> tuple[dict[str, np.ndarray], int]:
    """Step ``scenarios`` (suite rows ``index``) in chunks; returns (per-scenario arrays, steps)."""
    if chunk_size < 1:
        raise ValueError("chunk_size must be >= 1")
    cfg = suite.config
    held = hold_steps(cfg.decision_interval, getattr(decider, "action_repeat", 1))
    # Safety net: the core ends every row at its time limit; more steps than that means a bug.
    max_steps = int(math.ceil(float(np.max(scenarios.time_limit, initial=0.0)) / cfg.dt)) + 10
    parts: list[dict[str, np.ndarray]] = [_per_scenario_empty()]
    total_steps = 0
    bar = tqdm(total=scenarios.num, unit="scen", desc=f"{suite.name}/{decider.name}", leave=False,
               disable=not progress or not sys.stderr.isatty())
    try:
        for lo in range(0, scenarios.num, chunk_size):
            chunk = scenarios.take(slice(lo, lo + chunk_size))
            core = OvertakeCore(cfg)
            obs = core.reset(chunk)
            decider.reset()
            if getattr(decider, "privileged", False):
                decider.bind(core)
            if recorder is not None:
                recorder.begin_chunk(core, index[lo:lo + chunk.num])
            record = None if recorder is None else (lambda modes, res: recorder.record_step(core, modes, res))
            step = 0
            while not core.done.all():
                if step >= max_steps:
                    raise RuntimeError(f"rows still running after {max_steps} steps (time limit not enforced?)")
                res = hold(core, decider.act(obs), held, on_step=record)
                obs = res.obs
                bar.update(int(np.count_nonzero(res.finished)))
                step += res.steps
            total_steps += step
            if recorder is not None:
                recorder.end_chunk(core)
            parts.append(_per_scenario(core))
    finally:
        bar.close()
    per = round_per_scenario({k: np.concatenate([p[k] for p in parts]) for k in PER_SCENARIO})
    return per, total_steps


def _per_scenario_empty() -> dict[str, np.ndarray]:
    return {k: np.zeros(0, dtype) for k, (dtype, _) in PER_SCENARIO.items()}


def _per_scenario(core: OvertakeCore) -> dict[str, np.ndarray]:
    info, sc = core.info(), core.scen
    has_npc2 = sc.num_npcs > 1
    return {
        "outcome": info["outcome"], "crash_npc": info["crash_npc"], "crash_lane": info["crash_lane"],
        "completion_time": info["completion_time"], "episode_time": info["t"], "aborts": info["aborts"],
        "switches": info["switches"], "opposite_time": info["opposite_time"], "min_ttc": info["min_ttc"],
        "peak_lat_accel": info["peak_lat_accel"], "peak_jerk": info["peak_jerk"],
        # Initial NPC speeds, for the paper's "mean NPC speed in failed scenarios" rows; NPC2 is slot 1.
        "npc1_speed": np.where(sc.npc_present[:, 0], sc.npc_v[:, 0], np.nan),
        "npc2_speed": (np.where(sc.npc_present[:, 1] & (sc.npc_lane[:, 1] == 1), sc.npc_v[:, 1], np.nan) if has_npc2
                       else np.full(sc.num, np.nan)),
    }
