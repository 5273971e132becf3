"""Array backends for the core: numpy on the CPU (the default) or torch (CPU or CUDA).

The simulation model is written once against the small namespace below; each backend maps it to
its library. Reductions take one axis and are applied to batch-last arrays, so on numpy they are
fast elementwise passes (see core.py). The numpy backend returns numpy arrays everywhere; the torch
backend keeps every state array a tensor on its device.
"""

from __future__ import annotations

import builtins
from collections.abc import Callable
from typing import Any, Protocol, TypeAlias

import numpy as np

# An array of either backend: a numpy ndarray (NumpyBackend) or a torch Tensor (TorchBackend). The model
# is written once for both, so statically an array is either one: Any, named for what it stands for.
Array: TypeAlias = Any


class Backend(Protocol):
    """The namespace the core and the model (envs/model/) compute with: ``xp`` (both backends below).
    Reductions take one ``axis``; ``float``, ``int``, ``int8`` and ``bool`` are the backend's dtypes."""

    name: str
    float: Any
    int: Any
    int8: Any
    bool: Any

    def where(self, cond: Array, a: Array, b: Array, /) -> Array: ...
    def minimum(self, a: Array, b: Array, /) -> Array: ...
    def maximum(self, a: Array, b: Array, /) -> Array: ...
    def abs(self, x: Array, /) -> Array: ...
    def cos(self, x: Array, /) -> Array: ...
    def sin(self, x: Array, /) -> Array: ...
    def tan(self, x: Array, /) -> Array: ...
    def arctan(self, x: Array, /) -> Array: ...
    def arctan2(self, y: Array, x: Array, /) -> Array: ...
    def sqrt(self, x: Array, /) -> Array: ...
    def isfinite(self, x: Array, /) -> Array: ...
    def ones_like(self, x: Array, /) -> Array: ...
    def amin(self, a: Array, /, axis: builtins.int = 0, *, keepdims: builtins.bool = False) -> Array: ...
    def any(self, a: Array, /, axis: builtins.int = 0) -> Array: ...
    def all(self, a: Array, /, axis: builtins.int = 0) -> Array: ...
    def sum(self, a: Array, /, axis: builtins.int = 0) -> Array: ...
    def cumsum(self, a: Array, /) -> Array: ...
    def concatenate(self, xs: Any, /, axis: builtins.int = 0) -> Array: ...
    def stack(self, xs: Any, /, axis: builtins.int = 0) -> Array: ...
    def zeros(self, shape: Any, dtype: Any = None) -> Array: ...
    def full(self, shape: Any, value: Any, dtype: Any = None) -> Array: ...
    def arange(self, n: builtins.int) -> Array: ...
    def asarray(self, x: Any, dtype: Any = None) -> Array: ...
    def batch_last(self, x: Any, dtype: Any = None) -> Array: ...
    def astype(self, x: Array, dtype: Any) -> Array: ...
    def copy(self, x: Array) -> Array: ...
    def nonzero(self, mask: Array) -> Array: ...
    def nonzero2(self, mask: Array) -> tuple[Array, ...]: ...
    def to_numpy(self, x: Any) -> np.ndarray: ...
    def scatter_add(self, out: Array, index: Array, values: Array) -> None: ...

    # Sync-free stepping (a GPU): ``some(mask)`` is the guard of a branch that only saves work when
    # ``mask`` is all False; a sync-free backend answers True without reading the mask (reading it
    # would wait for the device), and the branch computes what skipping it would have given.
    sync_free: builtins.bool

    def some(self, mask: Array, /) -> builtins.bool: ...


class NumpyBackend:
    name = "numpy"
    float = np.float64
    int = np.int64
    int8 = np.int8
    bool = np.bool_

    where = staticmethod(np.where)
    minimum = staticmethod(np.minimum)
    maximum = staticmethod(np.maximum)
    abs = staticmethod(np.abs)
    cos, sin, tan = staticmethod(np.cos), staticmethod(np.sin), staticmethod(np.tan)
    arctan, arctan2, sqrt = staticmethod(np.arctan), staticmethod(np.arctan2), staticmethod(np.sqrt)
    isfinite = staticmethod(np.isfinite)
    ones_like = staticmethod(np.ones_like)
    # ufunc reductions skip numpy's Python-level wrappers, which dominate at N = 1.
    # (typed loosely: through staticmethod, numpy's stubs keep only reduce's first overload, keepdims=False)
    amin: Callable[..., np.ndarray] = staticmethod(np.minimum.reduce)
    any = staticmethod(np.logical_or.reduce)
    all = staticmethod(np.logical_and.reduce)
    sum = staticmethod(np.add.reduce)
    cumsum = staticmethod(np.cumsum)
    concatenate = staticmethod(np.concatenate)
    sync_free = False

    def __init__(self, device: Any = None, dtype: Any = None, sync_free: Any = None) -> None:
        self.float = np.dtype(dtype or np.float64).type

    @staticmethod
    def some(mask: np.ndarray) -> builtins.bool:
        return builtins.bool(mask.any())

    def zeros(self, shape: Any, dtype: Any = None) -> np.ndarray:
        return np.zeros(shape, dtype or self.float)

    @staticmethod
    def stack(xs: Any, axis: builtins.int = 0) -> np.ndarray:
        # np.array of small equal-shape arrays is np.stack on axis 0 without its Python-level checks
        # (4x faster at N = 1); for large arrays np.stack's plain copies are faster.
        return np.array(xs) if axis == 0 and xs[0].size <= 256 else np.stack(xs, axis)

    def full(self, shape: Any, value: Any, dtype: Any = None) -> np.ndarray:
        return np.full(shape, value, dtype or self.float)

    def arange(self, n: builtins.int) -> np.ndarray:
        return np.arange(n)

    def asarray(self, x: Any, dtype: Any = None) -> np.ndarray:
        return np.asarray(x, dtype=dtype)

    def batch_last(self, x: Any, dtype: Any = None) -> np.ndarray:
        """(N, M) -> a contiguous (M, N) array."""
        return np.ascontiguousarray(np.asarray(x, dtype=dtype).T)

    def astype(self, x: np.ndarray, dtype: Any) -> np.ndarray:
        return x.astype(dtype)

    def copy(self, x: np.ndarray) -> np.ndarray:
        return x.copy()

    def nonzero(self, mask: np.ndarray) -> np.ndarray:
        return np.flatnonzero(mask)

    def nonzero2(self, mask: np.ndarray) -> tuple[np.ndarray, ...]:
        return np.nonzero(mask)

    def to_numpy(self, x: Any) -> np.ndarray:
        return x

    @staticmethod
    def scatter_add(out: np.ndarray, index: np.ndarray, values: np.ndarray) -> None:
        """``out[index[i, j], j] += values[i, j]`` (repeated indices add up)."""
        np.add.at(out, (index, np.arange(out.shape[1])[None, :]), values)


class TorchBackend:
    """The same namespace over torch tensors on ``device`` (float64 by default, so results match
    numpy to rounding; float32 trades that for GPU speed). ``sync_free`` (default: on a GPU) never
    reads a device value on the host inside a step (see :meth:`some`)."""

    name = "torch"

    def __init__(self, device: Any = None, dtype: Any = None, sync_free: Any = None) -> None:
        import torch

        self.torch = torch
        self.device = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
        self.sync_free = bool(self.device.type != "cpu" if sync_free is None else sync_free)
        self._scalars: dict[tuple[type, str], Any] = {}
        self.float = dtype or torch.float64
        self.int, self.int8, self.bool = torch.int64, torch.int8, torch.bool
        self.cos, self.sin, self.tan, self.arctan = torch.cos, torch.sin, torch.tan, torch.atan
        self.arctan2, self.sqrt, self.isfinite, self.abs = torch.atan2, torch.sqrt, torch.isfinite, torch.abs
        self.ones_like = torch.ones_like

    def _t(self, x: Any) -> Any:
        if isinstance(x, self.torch.Tensor):
            return x
        if isinstance(x, bool | int | float):
            # A Python scalar becomes a cached 0-d tensor: made once by a fill on the device (no copy from
            # the host, which a CUDA graph capture forbids); floats follow the backend's float dtype.
            key = (type(x), repr(x))  # (repr: NaN is one key)
            if key not in self._scalars:
                dtype = self.float if isinstance(x, float) else self.torch.bool if isinstance(x, bool) else self.int
                self._scalars[key] = self.torch.full((), x, dtype=dtype, device=self.device)
            return self._scalars[key]
        return self.torch.as_tensor(x, device=self.device)

    def where(self, cond: Any, a: Any, b: Any) -> Any:
        a, b = self._t(a), self._t(b)
        if a.dtype != b.dtype and a.is_floating_point() != b.is_floating_point():
            dtype = a.dtype if a.is_floating_point() else b.dtype
            a, b = a.to(dtype), b.to(dtype)
        return self.torch.where(self._t(cond), a, b)

    def minimum(self, a: Any, b: Any) -> Any:
        if not isinstance(b, self.torch.Tensor):
            return self.torch.clamp(self._t(a), max=b)
        if not isinstance(a, self.torch.Tensor):
            return self.torch.clamp(b, max=a)
        return self.torch.minimum(a, b)

    def maximum(self, a: Any, b: Any) -> Any:
        if not isinstance(b, self.torch.Tensor):
            return self.torch.clamp(self._t(a), min=b)
        if not isinstance(a, self.torch.Tensor):
            return self.torch.clamp(b, min=a)
        return self.torch.maximum(a, b)

    def amin(self, a: Any, axis: int = 0, keepdims: bool = False) -> Any:
        return self.torch.amin(a, dim=axis, keepdim=keepdims)

    def any(self, a: Any, axis: int = 0) -> Any:
        return self.torch.any(a, dim=axis)

    def all(self, a: Any, axis: int = 0) -> Any:
        return self.torch.all(a, dim=axis)

    def sum(self, a: Any, axis: int = 0) -> Any:
        return self.torch.sum(a, dim=axis)

    def cumsum(self, a: Any) -> Any:
        return self.torch.cumsum(a, dim=0)

    def concatenate(self, xs: Any, axis: int = 0) -> Any:
        return self.torch.cat([self._t(x) for x in xs], dim=axis)

    def stack(self, xs: Any, axis: int = 0) -> Any:
        return self.torch.stack(list(xs), dim=axis)

    def zeros(self, shape: Any, dtype: Any = None) -> Any:
        return self.torch.zeros(shape, dtype=self._dtype(dtype or self.float), device=self.device)

    def full(self, shape: Any, value: Any, dtype: Any = None) -> Any:
        return self.torch.full(
            shape if isinstance(shape, tuple) else (shape,),
            value,
            dtype=self._dtype(dtype or self.float),
            device=self.device,
        )

    def arange(self, n: int) -> Any:
        return self.torch.arange(n, device=self.device)

    def asarray(self, x: Any, dtype: Any = None) -> Any:
        dtype = self._dtype(dtype) if dtype is not None else None
        if isinstance(x, np.ndarray) and dtype is None and x.dtype.kind == "f":
            dtype = self.float
        return self.torch.as_tensor(
            np.asarray(x) if not isinstance(x, self.torch.Tensor) else x, dtype=dtype, device=self.device
        )

    def batch_last(self, x: Any, dtype: Any = None) -> Any:
        return self.asarray(np.ascontiguousarray(np.asarray(x).T), dtype)

    def astype(self, x: Any, dtype: Any) -> Any:
        return x.to(self._dtype(dtype))

    def copy(self, x: Any) -> Any:
        return x.clone()

    def some(self, mask: Any) -> bool:
        return True if self.sync_free else bool(mask.any())

    def nonzero(self, mask: Any) -> Any:
        return self.torch.nonzero(mask).flatten()

    def nonzero2(self, mask: Any) -> tuple[Any, ...]:
        return self.torch.nonzero(mask, as_tuple=True)

    def to_numpy(self, x: Any) -> np.ndarray:
        return x.detach().cpu().numpy() if isinstance(x, self.torch.Tensor) else np.asarray(x)

    def scatter_add(self, out: Any, index: Any, values: Any) -> None:
        out.scatter_add_(0, index, values)

    def _dtype(self, dtype: Any) -> Any:
        t = self.torch
        mapping = {
            np.float64: t.float64,
            np.float32: t.float32,
            np.int64: t.int64,
            np.int8: t.int8,
            np.bool_: t.bool,
            float: self.float,
            int: t.int64,
            bool: t.bool,
        }
        return mapping.get(dtype, dtype)


def make_backend(name: str = "numpy", device: Any = None, dtype: Any = None, sync_free: Any = None) -> Backend:
    if name == "numpy":
        return NumpyBackend(device, dtype)
    if name == "torch":
        return TorchBackend(device, dtype, sync_free)
    raise ValueError(f"backend: {name!r} is not 'numpy' or 'torch'")


def to_host(value: Any) -> Any:
    """``value`` with every torch tensor in it (also inside tuples, lists, dicts and dataclasses such
    as StepResult) turned into a numpy array; numpy arrays and everything else pass unchanged."""
    if type(value).__module__.startswith("torch"):  # (a tensor; checked without importing torch)
        return value.detach().cpu().numpy()
    if isinstance(value, dict):
        return {k: to_host(v) for k, v in value.items()}
    if isinstance(value, tuple | list):
        return type(value)(to_host(v) for v in value)
    if hasattr(value, "__dataclass_fields__"):
        import dataclasses

        fields = {f.name: to_host(getattr(value, f.name)) for f in dataclasses.fields(value)}
        return dataclasses.replace(value, **fields)
    return value


NUMPY_DEVICE = "cpu"  # the default device: the numpy core on the CPU


def core_backend(device: str | None = None, backend: str | None = None) -> dict[str, Any]:
    """The core's ``backend`` and ``device`` keywords for a command's ``--device`` / ``--backend``:
    ``cpu`` is the numpy core (the default, the reference bits); ``cuda`` / ``cuda:N`` is the torch
    core on that GPU (float64: the same per-scenario results as numpy); ``--backend torch`` with
    ``--device cpu`` runs the torch core on the CPU (how the GPU path is tested without a GPU).
    Raises ValueError with one line for a device that is not there."""
    device = (device or NUMPY_DEVICE).strip().lower()
    if not (device == "cpu" or device == "cuda" or (device.startswith("cuda:") and device[5:].isdigit())):
        raise ValueError(f"--device {device!r}: expected cpu, cuda or cuda:N")
    backend = backend or ("numpy" if device == "cpu" else "torch")
    if backend not in ("numpy", "torch"):
        raise ValueError(f"--backend {backend!r}: expected numpy or torch")
    if backend == "numpy":
        if device != "cpu":
            raise ValueError(f"--device {device}: the numpy core runs on the CPU; use --backend torch or leave it out")
        return {"backend": "numpy", "device": None}
    try:
        import torch
    except ImportError:
        raise ValueError("--backend torch needs torch (pip install 'overtakezoo[train]')") from None
    if device != "cpu":
        if not torch.cuda.is_available():
            raise ValueError(f"--device {device}: torch {torch.__version__} sees no CUDA device on this machine")
        index = int(device[5:]) if ":" in device else 0
        if index >= torch.cuda.device_count():
            raise ValueError(f"--device {device}: this machine has {torch.cuda.device_count()} CUDA device(s)")
    return {"backend": "torch", "device": device}
