"""Many leaderboard rows re-run as one batch: their deciders stacked into one (each row a block of the
batch), grouped so that a batch needs one kind of decider; torch held to one thread meanwhile."""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator
from typing import Any

import numpy as np

from overtakezoo.benchmark.run.sandbox import PolicyFailure


def batches(todo: list, chunk_size: int) -> list[list]:
    """Rows stepped together in one batch (fewer Python steps). Only deciders that hold their
    decisions equally long share a batch (the runner holds one batch as one); privileged deciders
    bind the whole core, so each runs alone."""
    out: list[list] = []
    size, key = 0, None
    for item in sorted(todo, key=lambda it: batch_key(it[2])):  # stable
        n, privileged = item[1].size, getattr(item[2], "privileged", False)
        if not out or size + n > chunk_size or privileged or batch_key(item[2]) != key:
            out.append([])
            size, key = 0, batch_key(item[2])
        out[-1].append(item)
        size += n
    return out


def batch_key(decider: Any) -> tuple[bool, int]:
    return bool(getattr(decider, "privileged", False)), int(getattr(decider, "action_repeat", 1))


@contextlib.contextmanager
def torch_single_threaded() -> Iterator[None]:
    """Sampled rows are small batches: torch's intra-op threads only add synchronisation there (a
    forward pass took 36 ms instead of 0.7 ms on a busy 2-core machine)."""
    torch = sys.modules.get("torch")  # imported by the learned policies only
    if torch is None:
        yield
        return
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


class Stacked:
    """Several deciders on one batch: decider i acts on the next ``n_i`` roads. Roads never interact,
    so each decider's roads evolve exactly as in a run of its own. On a multi-AV batch (``num_avs``
    AV-major blocks of rows) decider i gets its roads' rows of every block, AV-major as in its own run.
    A failing part is named (``PolicyFailure.part``, rows in the whole batch) for the verifier."""

    name, version, privileged, weights_sha256 = "verify", "1", False, None

    def __init__(self, parts: list[tuple[Any, int]], num_avs: int = 1) -> None:
        bounds = np.cumsum([0] + [n for _, n in parts])
        self.parts = [(d, slice(int(a), int(b))) for (d, _), a, b in zip(parts, bounds[:-1], bounds[1:], strict=True)]
        self.action_repeat = int(getattr(parts[0][0], "action_repeat", 1))  # equal in a batch (batches)
        self.num_avs = num_avs

    def _mine(self, a: np.ndarray, rows: slice) -> np.ndarray:
        e = self.num_avs
        return a.reshape(e, -1, *a.shape[1:])[:, rows].reshape(-1, *a.shape[1:])

    def reset(self, mask: np.ndarray | None = None) -> None:
        for d, rows in self.parts:
            d.reset(None if mask is None else self._mine(np.asarray(mask), rows))

    def act(self, obs: np.ndarray) -> np.ndarray:
        from overtakezoo.benchmark.run.sandbox import check_modes

        out = np.empty((self.num_avs, obs.shape[0] // self.num_avs), np.int64)
        for i, (d, rows) in enumerate(self.parts):
            mine = self._mine(obs, rows)
            try:
                modes = check_modes(d.act(mine), mine.shape[0])
            except PolicyFailure as exc:
                n = rows.stop - rows.start
                bad = None if exc.rows is None else exc.rows % n + rows.start  # (AV-major rows of the part)
                failure = PolicyFailure(exc.reason, bad)
                failure.part = i
                raise failure from None
            out[:, rows] = modes.reshape(self.num_avs, -1)
        return out.reshape(-1)
