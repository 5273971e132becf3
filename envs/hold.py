"""The action hold: one decision drives the core for several steps. The one implementation used by
the benchmark runner, the Gymnasium / PettingZoo faces, the rsl-rl face and the trainers;
:func:`run_to_end` (a batch driven by one decider until every row is done) is built on it.

A decision is held for :func:`hold_steps` core steps: the configuration's ``decision_interval``
(how often the benchmark lets a decider act) rounded to the multiple of it nearest the decider's own
``action_repeat``, its *decision rate* (the core steps between its decisions when deployed: a
learned member's card's ``decide_every``, else its *training hold*, the card's ``action_repeat``,
the core steps each decision was held in training). :func:`hold` then steps the core that many
times under the same modes. An env face holds ``hold_steps`` core steps per env step: the zoo's
1 s (:func:`~overtakezoo.envs.suites.zoo_hold`) for a face made from a suite or a suite id, the
config's ``decision_interval`` for one made from a raw config.

A row whose episode ends during the hold stops counting: its reward, termination and (on an
auto-reset core) its final observation and info are those of its own episode. On a core without
auto-reset the finished row is frozen by the core; on an auto-reset core the refilled row follows
(the reset mode) until the hold ends, and those steps belong to no decision.

Several AVs on one road (multi-AV cores): an AV that is done waits frozen until every AV of its
road is done, and only then is the road refilled. A row already done when the decision is taken is
*waiting* (``HeldStep.waiting``): its decision belongs to no episode, so the hold treats it as a
finished row (no reward, no steps, the reset mode if its road is refilled during the hold) and a
trainer stores no transition for it. On a single-AV auto-reset core no row is ever waiting.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from overtakezoo.envs.config import FOLLOW
from overtakezoo.envs.core import OvertakeCore, StepResult


class SteppedCore(Protocol):
    """What :func:`hold` steps: an :class:`OvertakeCore`, or a batch stepped like one (a
    :class:`~overtakezoo.envs.mixture.MixedCore`)."""

    auto_reset: bool

    @property
    def done(self) -> Any: ...  # (N,) bool

    def step(self, modes: Any, npc_accel: Any = None) -> StepResult: ...


def hold_steps(decision_interval: int, action_repeat: int = 1) -> int:
    """Core steps one decision is held: ``decision_interval`` times ``round(action_repeat /
    decision_interval)``, at least one interval (a decider trained at 10 steps per decision under a
    suite deciding every step is held 10 steps; under a suite deciding every 4 steps, 8)."""
    interval, repeat = int(decision_interval), int(action_repeat)
    if interval < 1 or repeat < 1:
        raise ValueError(f"decision_interval and action_repeat must be >= 1, got {interval} and {repeat}")
    return interval * max(1, round(repeat / interval))


@dataclass
class HeldStep:
    """What :func:`hold` returns; every array has one entry per row."""

    obs: np.ndarray  # (N, D) after the last step (a refilled row's new episode on an auto-reset core)
    reward: np.ndarray  # (N,) summed over the row's own steps
    terminated: np.ndarray  # (N,) bool: the row's episode terminated during the hold
    truncated: np.ndarray  # (N,) bool: ... or hit its time limit
    finished: np.ndarray  # (N,) bool: terminated | truncated
    live_steps: np.ndarray  # (N,) int: core steps the row's episode ran during the hold
    final_obs: np.ndarray | None  # (N, D) the finished rows' last observation (auto-reset cores only)
    final_info: dict[str, np.ndarray] | None  # per-row info at each finished row's end (auto-reset only)
    info: dict[str, np.ndarray]  # the last step's info
    steps: int  # core steps taken (fewer than asked when every row was done)
    waiting: np.ndarray | None = None  # (N,) bool: rows already done at the decision (no episode running)


def hold(
    core: SteppedCore,
    modes: Any,
    steps: int,
    npc_accel: np.ndarray | None = None,
    on_step: Callable[[np.ndarray, StepResult], None] | None = None,
) -> HeldStep:
    """Step ``core`` ``steps`` times under ``modes`` (and ``npc_accel``), stopping early once every
    row is done. ``on_step(modes, result)`` sees every core step (e.g. a recorder)."""
    modes = np.asarray(modes, dtype=np.int64).reshape(-1)
    n = modes.shape[0]
    reward = np.zeros(n)
    terminated, truncated, ended = np.zeros(n, bool), np.zeros(n, bool), np.zeros(n, bool)
    live_steps = np.zeros(n, np.int64)
    final_obs, final_info = None, None
    waiting = np.array(core.done, dtype=bool).reshape(n)  # done before the decision: no episode of theirs runs
    res, taken = None, 0
    for _ in range(int(steps)):
        if taken and core.done.all():
            break
        # Rows running at this step: a held core freezes its finished rows (zero reward); an
        # auto-reset row that ended (or was waiting) may be refilled, and its new episode is not
        # this decision's.
        idle = ended | waiting
        active = ~idle if core.auto_reset else ~ended & ~np.asarray(core.done)
        step_modes = np.where(idle, FOLLOW, modes) if core.auto_reset and idle.any() else modes
        res = core.step(step_modes, npc_accel)
        taken += 1
        if on_step is not None:
            on_step(step_modes, res)
        reward += np.where(active, res.reward, 0.0)
        live_steps += active
        now = active & res.finished
        terminated |= now & res.terminated
        truncated |= now & res.truncated
        if core.auto_reset and now.any():
            if final_obs is None:
                final_obs = np.array(res.obs)
                final_info = {k: np.array(v) for k, v in res.info.items()}
            assert final_info is not None and res.final_obs is not None  # (an auto-reset step that ended rows)
            final_obs[now] = res.final_obs[now]
            for k in final_info:
                final_info[k][now] = res.info[k][now]
        ended |= now
    if res is None:
        raise ValueError("hold: steps must be >= 1 (and the core reset)")
    return HeldStep(
        res.obs, reward, terminated, truncated, ended, live_steps, final_obs, final_info, res.info, taken, waiting
    )


def run_to_end(
    core: OvertakeCore,
    obs: Any,
    decide: Callable[[Any, int], Any],
    steps: int,
    on_step: Callable[[np.ndarray, StepResult], None] | None = None,
    on_hold: Callable[[HeldStep], None] | None = None,
    max_steps: int | None = None,
    compact: Callable[[Any], tuple[OvertakeCore, Any] | None] | None = None,
) -> int:
    """Drive every row of ``core`` (reset, without auto-reset) to the end of its episode:
    ``decide(obs, step)`` gives the modes at core step ``step``, each held ``steps`` core steps;
    ``on_hold`` sees each :class:`HeldStep`; ``compact(obs)``, after each hold, may return a smaller
    core (finished rows dropped) and its observations to go on with. Returns the core steps taken;
    more than ``max_steps`` is a RuntimeError (the core ends every row at its time limit)."""
    taken = 0
    while not core.done.all():
        if max_steps is not None and taken >= max_steps:
            raise RuntimeError(f"rows still running after {max_steps} steps (time limit not enforced?)")
        res = hold(core, decide(obs, taken), steps, on_step=on_step)
        if on_hold is not None:
            on_hold(res)
        obs, taken = res.obs, taken + res.steps
        smaller = compact(obs) if compact is not None else None
        if smaller is not None:
            core, obs = smaller
    return taken
