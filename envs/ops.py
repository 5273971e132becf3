"""Array helpers shared by the planner, the controllers and the core (numpy or torch via ``xp``)."""

from __future__ import annotations

import numpy as np

from overtakezoo.envs.backend import NumpyBackend

INF = float("inf")
NP = NumpyBackend()


def clip(x, lo, hi, xp=NP):
    """``np.clip`` without its Python-level dispatch (it dominates at N = 1)."""
    return xp.minimum(xp.maximum(x, lo), hi)


# Up to this many rows (the batch, the last axis) numpy's own argmin/argmax is cheaper than the
# elementwise passes below: at small N each numpy call costs ~1 us whatever its size.
SMALL_BATCH = 256


def first_argmin(a: np.ndarray, axis: int = 0, xp=NP) -> np.ndarray:
    """Index of the first minimum along ``axis``, like ``argmin``. The core keeps the batch as the
    last (contiguous) axis; numpy's argmin over a leading axis copies a transpose and its reductions
    over a short trailing axis cost ~20 ns per row, so both are avoided with fast elementwise passes."""
    if xp.name == "numpy" and a.shape[-1] <= SMALL_BATCH:
        return a.argmin(axis=axis)
    low = xp.amin(a, axis=axis, keepdims=True)
    return first_true(a == low, axis, xp)


def first_true(mask: np.ndarray, axis: int = 0, xp=NP) -> np.ndarray:
    """Index of the first True along ``axis`` (the axis length where there is none)."""
    length = mask.shape[axis]
    if xp.name == "numpy" and mask.shape[-1] <= SMALL_BATCH:
        return np.where(mask.any(axis=axis), mask.argmax(axis=axis), length)
    index = xp.arange(length).reshape((-1,) + (1,) * (mask.ndim - 1 - axis % mask.ndim))
    return xp.amin(xp.where(mask, index, length), axis=axis)
