"""Several auto-reset cores stepped as one batch: training over a mixture of suites.

Suites differ in their simulator settings (planner margins, prediction, the number of NPC slots),
which one :class:`OvertakeCore` holds for all its rows, so a mixture keeps one core per suite and
concatenates their rows (one per AV of each road): rows ``[0, n_0)`` belong to the first core, the
next ``n_1`` to the second, and so on. Each core refills its own finished rows from its own source,
so every row keeps drawing from its suite and the mixture's proportions stay fixed. The observation
layouts must agree (the same planner rollouts and observation slots), which every built-in suite's
does.

It offers what :func:`overtakezoo.envs.hold.hold` and the trainers use (``step``, ``done``,
``auto_reset``, ``num``, ``observe``), so a trainer steps a mixture as it steps one core.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from overtakezoo.envs.config import EnvConfig
from overtakezoo.envs.core import OvertakeCore, StepResult
from overtakezoo.envs.model.observation import observation_layout
from overtakezoo.envs.scenarios import Scenarios

Source = Callable[[int, np.random.Generator], Scenarios]


def split_rows(total: int, parts: int) -> list[int]:
    """``total`` rows over ``parts`` cores as evenly as possible (the first ones get the remainder)."""
    if parts < 1 or total < parts:
        raise ValueError(f"cannot split {total} rows over {parts} suites: need at least one row each")
    return [total // parts + (i < total % parts) for i in range(parts)]


class MixedCore:
    """``cores[i]`` steps ``sizes[i]`` roads drawn from ``sources[i]`` (one row per AV of each road);
    rows are concatenated in order."""

    auto_reset = True

    def __init__(
        self, configs: Sequence[EnvConfig], sources: Sequence[Source], sizes: Sequence[int], seed: int | None = None
    ) -> None:
        if not (len(configs) == len(sources) == len(sizes)) or not configs:
            raise ValueError("one config, source and size per mixture component")
        layouts = {tuple((k, s.start, s.stop) for k, s in observation_layout(c).items()) for c in configs}
        if len(layouts) != 1:
            raise ValueError("a mixture needs one observation layout (same planner rollouts and slots)")
        seeds = np.random.SeedSequence(seed).spawn(len(configs))
        self.cores = [
            OvertakeCore(c, auto_reset=True, source=src, seed=np.random.default_rng(s))
            for c, src, s in zip(configs, sources, seeds, strict=True)
        ]
        self.sizes = [int(n) for n in sizes]
        self._obs = np.concatenate(
            [core.reset(src(n, core.rng)) for core, src, n in zip(self.cores, sources, self.sizes, strict=True)]
        )

    @property
    def num(self) -> int:
        """Rows: one per automated vehicle (``sizes`` count roads; a multi-AV road has several)."""
        return sum(core.num for core in self.cores)

    @property
    def cfg(self) -> EnvConfig:
        return self.cores[0].cfg

    @property
    def done(self) -> np.ndarray:
        return np.concatenate([np.asarray(c.done) for c in self.cores])

    def observe(self) -> np.ndarray:
        return self._obs

    def step(self, modes: Any, npc_accel: Any = None) -> StepResult:
        if npc_accel is not None:
            raise ValueError("a mixture has no NPC agents")
        modes = np.asarray(modes)
        parts, start = [], 0
        for core in self.cores:
            parts.append(core.step(modes[start : start + core.num]))
            start += core.num
        res = _concat(parts)
        self._obs = res.obs
        return res


def _concat(parts: list[StepResult]) -> StepResult:
    cat = np.concatenate
    info = {k: cat([np.asarray(p.info[k]) for p in parts]) for k in parts[0].info}
    final = (
        None
        if all(p.final_obs is None for p in parts)
        else cat([p.obs if p.final_obs is None else p.final_obs for p in parts])
    )
    return StepResult(
        cat([p.obs for p in parts]),
        cat([p.reward for p in parts]),
        cat([p.terminated for p in parts]),
        cat([p.truncated for p in parts]),
        final,
        info,
    )
