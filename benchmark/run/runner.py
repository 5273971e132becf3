"""Run a decider on a suite: the whole suite as one batch (in chunks to bound memory).

The runner applies the action hold (``overtakezoo.envs.hold``): the decider acts on the batch's
observations, and each decision is held for ``hold_steps(decision_interval, decider.action_repeat)``
core steps; finished rows are frozen by the core, so the loop simply steps until every row is done.

Finished rows are dropped from the batch (:class:`Compaction`) once at most half of it still runs,
where every part with per-row state can drop them: the decider (a declared ``row_state``), the
recorder (``keep_rows``) and the safety monitor. Rows never interact, so the results are the same
bits either way (``tests/benchmark/test_benchmark_runner.py`` checks it); single-ego suites only.

On a multi-AV suite the decider drives every AV (self-play), or a :class:`~.pairing.Pairing` drives
AV e with its e-th decider (cross-play); the per-scenario arrays then hold one value per AV,
AV-major (results.py).
"""

from __future__ import annotations

import math
import sys
import time
from datetime import UTC, datetime
from typing import Any

import numpy as np
from tqdm import tqdm

from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.results import registry
from overtakezoo.benchmark.results.results import Results, round_per_scenario
from overtakezoo.benchmark.results.schema import recorded_keys
from overtakezoo.benchmark.run.sandbox import PolicyFailure, check_modes
from overtakezoo.benchmark.safety import SafetyMonitor
from overtakezoo.envs import OvertakeCore
from overtakezoo.envs.backend import core_backend
from overtakezoo.envs.hold import hold_steps, run_to_end
from overtakezoo.envs.host import host_core
from overtakezoo.envs.scenarios import EGO_LANE, NPC1_SLOT, npc1_npc2_speeds
from overtakezoo.envs.suites import CHUNK_SIZE, Suite, shard_bounds
from overtakezoo.zoo.members.learned import read_parts


def run_suite(
    suite: Suite,
    decider: Any,
    shard: tuple[int, int] | None = None,
    chunk_size: int = CHUNK_SIZE,
    progress: bool = True,
    recorder: Any = None,
    limit: int | None = None,
    safety: bool = True,
    device: str | None = None,
    backend: str | None = None,
) -> Results:
    """Evaluate ``decider`` on ``suite`` (or its shard ``(i, k)``, 0-based) and return the results.

    ``recorder`` (optional) gets ``begin_chunk(core, scenario_index)``, ``record_step(core, modes,
    step_result)`` after every step and ``end_chunk(core)``; its creator closes it. ``limit`` keeps
    only the first ``limit`` scenarios of the (shard's) range. ``safety`` (default on) records the
    safety metrics (benchmark/safety, docs/metrics.md); off, the file has only the older arrays.
    ``device`` / ``backend`` pick the core (envs/backend.py ``core_backend``: the numpy core by
    default; ``cuda`` runs the torch core on a GPU in float64, with the same per-scenario results).
    """
    start, stop = shard_bounds(suite.count, shard)
    scenarios = suite.scenarios(shard)
    _check_multi_av(suite, scenarios, decider, recorder)
    if limit is not None:
        stop = min(stop, start + limit)
        scenarios = scenarios.take(slice(0, stop - start))
    t0, started = time.perf_counter(), datetime.now(UTC)
    per, total_steps = _run(
        suite, decider, scenarios, np.arange(start, stop), chunk_size, progress, recorder, safety, device, backend
    )
    timing = {
        "wall_time_s": round(time.perf_counter() - t0, 3),
        "started": started.isoformat(timespec="seconds"),
        "steps": total_steps,
    }
    return Results.create(
        suite, decider, per, start=start, stop=stop, shard=shard, timing=timing, num_avs=scenarios.num_avs
    )


def run_indices(
    suite: Suite,
    decider: Any,
    indices: np.ndarray,
    chunk_size: int = CHUNK_SIZE,
    safety: bool = True,
    device: str | None = None,
    backend: str | None = None,
) -> dict[str, np.ndarray]:
    """Per-scenario arrays (rounded as results files store them) for the suite's scenarios ``indices``.

    The whole suite is drawn and the rows taken, and rows never interact, so each value equals the
    same scenario's value in a full run (what ``leaderboard --verify`` relies on)."""
    indices = np.asarray(indices, dtype=np.int64)
    if indices.size and not (0 <= indices.min() and indices.max() < suite.count):
        raise ValueError(f"scenario indices must lie in [0, {suite.count})")
    return run_scenarios(suite, decider, suite.scenarios().take(indices), indices, chunk_size, safety, device, backend)


def run_scenarios(
    suite: Suite,
    decider: Any,
    scenarios: Any,
    labels: np.ndarray,
    chunk_size: int = CHUNK_SIZE,
    safety: bool = True,
    device: str | None = None,
    backend: str | None = None,
) -> dict[str, np.ndarray]:
    """Per-scenario arrays of ``decider`` on ``scenarios`` (any batch drawn from ``suite``'s distribution,
    run with its settings; ``labels`` name the rows in errors): what verify runs on a public sample, a
    fresh draw and its own draw at once."""
    _check_multi_av(suite, scenarios, decider, None)
    labels = np.asarray(labels, np.int64)
    return _run(suite, decider, scenarios, labels, chunk_size, False, None, safety, device, backend)[0]


def _check_multi_av(suite: Suite, scenarios: Any, decider: Any, recorder: Any) -> None:
    """What a multi-AV suite cannot run: clear errors instead of wrong rows."""
    if scenarios.num_avs == 1:
        return
    if getattr(decider, "privileged", False) and not getattr(decider, "joint", False):
        # The oracle simulates clones of its rows assuming nobody else decides; beside another AV it
        # would have to predict that AV's decider, so it is no upper bound there. The joint oracle
        # plans every AV of the road itself (zoo/members/joint_oracle.py).
        raise UserError(
            f"suite {suite.name!r} has {scenarios.num_avs} automated vehicles per scenario: {decider.name} "
            "is privileged and plans one AV, so it runs on single-ego suites only "
            "(joint-oracle plans every AV of a road)"
        )
    if recorder is not None:
        raise UserError(
            f"suite {suite.name!r} has {scenarios.num_avs} automated vehicles per scenario: archives "
            "record single-ego suites only"
        )


def _run(
    suite: Suite,
    decider: Any,
    scenarios: Any,
    index: np.ndarray,
    chunk_size: int,
    progress: bool,
    recorder: Any,
    safety: bool = True,
    device: str | None = None,
    backend: str | None = None,
) -> tuple[dict[str, np.ndarray], int]:
    """Step ``scenarios`` (suite rows ``index``) in chunks; returns (per-scenario arrays, steps)."""
    if chunk_size < 1:
        raise ValueError("chunk_size must be >= 1")
    try:
        on = core_backend(device, backend)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    # The suite's settings, with the opt-in observation parts the decider reads on (its config says so).
    parts = read_parts(decider)
    cfg = suite.config.with_observation(**parts) if parts else suite.config
    held = hold_steps(cfg.decision_interval, getattr(decider, "action_repeat", 1))
    # Safety net: the core ends every row at its time limit; more steps than that means a bug.
    max_steps = int(math.ceil(float(np.max(scenarios.time_limit, initial=0.0)) / cfg.dt)) + 10
    keys = recorded_keys(scenarios.num_avs, safety)
    parts: list[dict[str, np.ndarray]] = [_per_scenario_empty()]
    total_steps = 0
    compact = (
        scenarios.num_avs == 1
        and getattr(decider, "row_state", None) is not None
        and (recorder is None or hasattr(recorder, "keep_rows"))
    )
    bar = tqdm(
        total=scenarios.num * scenarios.num_avs,
        unit="AV",
        desc=f"{suite.name}/{decider.name}",
        leave=False,
        disable=not progress or not sys.stderr.isatty(),
    )
    try:
        for lo in range(0, scenarios.num, chunk_size):
            chunk = scenarios.take(slice(lo, lo + chunk_size))
            core = host_core(OvertakeCore(cfg, **on))  # (numpy: the core itself; torch: read from the host)
            obs = core.reset(chunk)
            decider.reset()
            if getattr(decider, "privileged", False):
                decider.bind(core)
            if recorder is not None:
                recorder.begin_chunk(core, index[lo : lo + chunk.num])
            monitor = SafetyMonitor() if safety else None
            if monitor is not None:
                monitor.begin_chunk(core)
            live = Compaction(core, index[lo : lo + chunk.num], decider, recorder, monitor, compact)
            total_steps += run_to_end(
                core,
                obs,
                lambda o, k, live=live: _decide(decider, o, live.rows, k, cfg.dt),
                held,
                on_step=live.on_step,
                max_steps=max_steps,
                compact=live.compact,
                on_hold=lambda res: bar.update(int(np.count_nonzero(res.finished))),
            )
            if recorder is not None:
                recorder.end_chunk(live.core)
            parts.append(live.finish())
    finally:
        bar.close()
    e = scenarios.num_avs  # AV-major: join each AV's part of every chunk
    per = round_per_scenario(
        {k: np.concatenate([p[k].reshape(e, -1) for p in parts], axis=1).reshape(-1) for k in keys}
    )
    return per, total_steps


MIN_COMPACT_ROWS = 64  # below this a smaller batch saves less than the copy costs


class Compaction:
    """One chunk's rows while they run: the core stepping them (smaller once finished rows are
    dropped), which suite rows they are, and the per-scenario values of the rows already dropped."""

    def __init__(
        self, core: OvertakeCore, rows: np.ndarray, decider: Any, recorder: Any, monitor: Any, enabled: bool
    ) -> None:
        self.core, self.rows, self.decider, self.recorder, self.monitor = core, rows, decider, recorder, monitor
        self.enabled, self.size = enabled, core.num
        self.pos = np.arange(core.num)  # chunk position of each current row
        self.dropped: list[tuple[np.ndarray, dict[str, np.ndarray]]] = []

    def on_step(self, modes: np.ndarray, res: Any) -> None:
        if self.recorder is not None:
            self.recorder.record_step(self.core, modes, res)
        if self.monitor is not None:
            self.monitor.record_step(self.core, modes, res)

    def _values(self) -> dict[str, np.ndarray]:
        """The per-scenario arrays of the current rows (final for the finished ones)."""
        return _per_scenario(self.core, self.monitor)

    def compact(self, obs: np.ndarray) -> tuple[OvertakeCore, np.ndarray] | None:
        """After a hold: drop the finished rows when at most half the batch still runs; returns the
        smaller core and its rows' observations, or None to go on with the same batch."""
        if not self.enabled or self.core.num < MIN_COMPACT_ROWS:
            return None
        done = np.asarray(self.core.done)
        keep = np.flatnonzero(~done)
        if 2 * keep.size > done.size or not keep.size:
            return None
        gone = np.ones(done.size, bool)
        gone[keep] = False
        self.dropped.append((self.pos[gone], {k: v[gone] for k, v in self._values().items()}))
        self.core, self.pos, self.rows = self.core.clone(keep), self.pos[keep], self.rows[keep]
        self.decider.keep_rows(keep, self.core)
        if self.recorder is not None:
            self.recorder.keep_rows(keep)
        if self.monitor is not None:
            self.monitor.keep_rows(keep)
        return self.core, obs[keep]

    def finish(self) -> dict[str, np.ndarray]:
        """Every row's per-scenario arrays, in the chunk's row order."""
        parts = [*self.dropped, (self.pos, self._values())]
        out = {}
        for key, value in parts[-1][1].items():
            out[key] = np.empty((self.size, *value.shape[1:]), value.dtype)
            for pos, values in parts:
                out[key][pos] = values[key]
        return out


class RunFailure(UserError):
    """A decider failed mid-run: one line naming it, the scenario and the step. ``part``: which
    decider of a stacked batch (verify's), when it was one."""

    def __init__(self, message: str, part: int | None = None) -> None:
        super().__init__(message)
        self.part = part


def _decide(decider: Any, obs: np.ndarray, scenarios: np.ndarray, step: int, dt: float) -> np.ndarray:
    """The decider's modes for ``obs`` (rows of the suite's ``scenarios``, AV-major when several
    AVs share a road), checked: (N,) integers in {0, 1, 2}; anything else is a :class:`RunFailure`."""
    try:
        return check_modes(decider.act(obs), obs.shape[0])
    except PolicyFailure as exc:
        rows = np.tile(scenarios, max(1, obs.shape[0] // max(1, scenarios.size)))
        where = (
            f"scenario {int(rows[exc.rows[0]])}"
            if exc.rows is not None and exc.rows.size
            else f"scenarios {int(scenarios.min())}-{int(scenarios.max())}"
            if scenarios.size
            else "no scenario"
        )
        raise RunFailure(
            f"{decider.name}: {where}, step {step} (t = {step * dt:.1f} s): {exc.reason}", getattr(exc, "part", None)
        ) from None


def _per_scenario_empty() -> dict[str, np.ndarray]:
    return {m.name: np.zeros(0, m.dtype) for m in registry.metrics()}


def _per_scenario(core: OvertakeCore, monitor: Any = None) -> dict[str, np.ndarray]:
    """Every array the run records (results/registry.py), each from its declared source."""
    sources = {
        registry.INFO: core.info(),
        registry.SCENARIO: _scenario_values(core),
        registry.MONITOR: monitor.end_chunk(core) if monitor is not None else {},
    }
    return {m.name: sources[m.source][m.source_key] for m in registry.recorded(core.num_avs, monitor is not None)}


def _scenario_values(core: OvertakeCore) -> dict[str, np.ndarray]:
    """The arrays taken from the scenario (registry source SCENARIO): the initial speeds of NPC1 and
    NPC2, for the paper's "mean NPC speed in failed scenarios" rows; on a multi-AV road, per AV row
    (AV-major, as the core), its own lead's slot and speed."""
    sc = core.scen
    if core.num_avs == 1:
        npc1_speed, npc2_speed = npc1_npc2_speeds(sc)
        return {"npc1_speed": npc1_speed, "npc2_speed": npc2_speed}
    e, n = core.num_avs, sc.num
    # Each AV's own lead (its NPC1): the ego's is NPC1's slot, the others' are av_lead.
    ego_lead = sc.npc_present[:, NPC1_SLOT] & (sc.npc_lane[:, NPC1_SLOT] == EGO_LANE)
    lead = np.concatenate([np.where(ego_lead, NPC1_SLOT, -1)[None], sc.av_lead.T.astype(np.int64)]).reshape(-1)
    lead_v = np.take_along_axis(np.tile(sc.npc_v, (e, 1)), np.maximum(lead, 0)[:, None], 1)[:, 0]
    return {
        "lead_npc": lead,
        "npc1_speed": np.where(lead >= 0, lead_v, np.nan),
        "npc2_speed": np.full(e * n, np.nan),  # no single "first oncoming car" beside other AVs
    }
