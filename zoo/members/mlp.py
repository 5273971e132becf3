"""Numpy inference for the learned members: an MLP forward pass from plain weight arrays.

Torch is for training only. A pretrained member is a few dense layers (tens of KB), so acting
through numpy saves the ~2 s import of torch on every ``overtakezoo eval`` process, and float64
matrix products make an argmax independent of how rows are batched.

Weights are stored as ``.npz`` written by :func:`npz_bytes`: the same arrays give the same bytes
(fixed zip timestamps, sorted names), so a weights sha256 identifies the parameters, not the moment
they were saved.
"""

from __future__ import annotations

import io
import zipfile
from dataclasses import dataclass
from typing import Any

import numpy as np

ACTIVATIONS = ("relu", "elu", "tanh")


@dataclass(frozen=True)
class NumpyMLP:
    """``layers`` = [(W (out, in), b (out,)), ...] in torch's ``nn.Linear`` layout; the activation
    follows every layer but the last. With ``dueling`` the last layer gives [value, advantages...]
    and the output is ``value + adv - mean(adv)`` (Wang et al. 2016)."""

    layers: tuple[tuple[np.ndarray, np.ndarray], ...]
    activation: str = "relu"
    dueling: bool = False

    def __post_init__(self) -> None:
        if self.activation not in ACTIVATIONS:
            raise ValueError(f"activation {self.activation!r}: expected one of {', '.join(ACTIVATIONS)}")
        width = None
        for i, (w, b) in enumerate(self.layers):
            if w.ndim != 2 or b.shape != (w.shape[0],) or (width is not None and w.shape[1] != width):
                raise ValueError(f"layer {i}: weight {w.shape} and bias {b.shape} do not chain")
            width = w.shape[0]
        if not self.layers:
            raise ValueError("an MLP needs at least one layer")

    @property
    def in_features(self) -> int:
        return int(self.layers[0][0].shape[1])

    @property
    def out_features(self) -> int:
        return int(self.layers[-1][0].shape[0]) - (1 if self.dueling else 0)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        h = np.asarray(x, np.float64)
        last = len(self.layers) - 1
        with _one_blas_thread():
            for i, (w, b) in enumerate(self.layers):
                h = h @ w.T + b
                if i < last:
                    h = _activate(h, self.activation)
        if self.dueling:
            value, adv = h[:, :1], h[:, 1:]
            h = value + adv - adv.mean(axis=1, keepdims=True)
        return h

    def arrays(self) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {}
        for i, (w, b) in enumerate(self.layers):
            out[f"layer{i}.weight"], out[f"layer{i}.bias"] = w, b
        return out

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], activation: str = "relu", dueling: bool = False) -> NumpyMLP:
        n = sum(1 for k in arrays if k.endswith(".weight"))
        try:
            layers = tuple(
                (np.asarray(arrays[f"layer{i}.weight"], np.float64), np.asarray(arrays[f"layer{i}.bias"], np.float64))
                for i in range(n)
            )
        except KeyError as exc:
            raise ValueError(f"weights lack {exc.args[0]}") from None
        return cls(layers, activation, dueling)

    @classmethod
    def from_linears(cls, linears: list[Any], activation: str = "relu", dueling: bool = False) -> NumpyMLP:
        """From torch ``nn.Linear`` modules in order (at export time, where torch is loaded)."""
        return cls(
            tuple(
                (lin.weight.detach().cpu().double().numpy(), lin.bias.detach().cpu().double().numpy())
                for lin in linears
            ),
            activation,
            dueling,
        )


_BLAS: Any = None


def _one_blas_thread() -> Any:
    """The matrix products on one BLAS thread: for layers this small it is as fast on an idle
    machine, a third of the CPU time on a loaded one (OpenBLAS threads spin while they wait), and
    the arithmetic does not depend on the machine's core count."""
    global _BLAS
    if _BLAS is None:
        from threadpoolctl import ThreadpoolController

        _BLAS = ThreadpoolController()
    return _BLAS.limit(limits=1, user_api="blas")


def _activate(h: np.ndarray, kind: str) -> np.ndarray:
    if kind == "relu":
        return np.maximum(h, 0.0)
    if kind == "elu":
        return np.where(h > 0.0, h, np.expm1(np.minimum(h, 0.0)))
    return np.tanh(h)


_EPOCH = (1980, 1, 1, 0, 0, 0)  # the earliest zip timestamp: fixed, so bytes depend on content only


def npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    """A ``.npz`` (readable by ``np.load``) whose bytes depend only on the arrays."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for name in sorted(arrays):
            member = io.BytesIO()
            np.lib.format.write_array(member, np.ascontiguousarray(arrays[name]), allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=_EPOCH)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            zf.writestr(info, member.getvalue())
    return buf.getvalue()


# A member's weights are ~100 KB; an outside .npz declaring more than this once inflated is refused
# before a byte is inflated (zipfile never yields more than a member's declared size).
MAX_NPZ_BYTES = 64 << 20


def read_npz(data: bytes) -> dict[str, np.ndarray]:
    """Arrays of an ``.npz`` held in memory (pickles refused; at most :data:`MAX_NPZ_BYTES` inflated)."""
    try:
        declared = sum(info.file_size for info in zipfile.ZipFile(io.BytesIO(data)).infolist())
    except zipfile.BadZipFile as exc:
        raise ValueError(f"not an .npz (zip) file: {exc}") from None
    if declared > MAX_NPZ_BYTES:
        raise ValueError(f"the .npz inflates to {declared} bytes, more than the {MAX_NPZ_BYTES} a weights file may")
    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}
