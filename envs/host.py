"""An :class:`~overtakezoo.envs.core.OvertakeCore` on the torch backend, seen from the host.

The benchmark's runner, its safety monitor, the privileged deciders and the recorders compute on
numpy arrays. :class:`HostCore` lets them drive a core whose state lives in torch tensors (on a GPU,
or on the CPU where that path is tested) unchanged: every array it hands out, as an attribute or as
what a method returns, is a numpy copy, and a clone is again a HostCore. The simulation itself runs
on the device; only what the host reads crosses (on the numpy backend :func:`host_core` returns the
core itself, so the default path pays nothing).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from overtakezoo.envs.backend import to_host
from overtakezoo.envs.core import OvertakeCore


class HostCore:
    """A torch-backed core whose every array read is a numpy array (see the module's docstring)."""

    def __init__(self, core: OvertakeCore) -> None:
        object.__setattr__(self, "_core", core)

    @property
    def device_core(self) -> OvertakeCore:
        """The wrapped core (its arrays are the backend's own)."""
        return self._core

    def __getattr__(self, name: str) -> Any:
        value = getattr(self._core, name)
        if callable(value) and not isinstance(value, type):
            return lambda *args, **kwargs: _host(value(*args, **kwargs))
        return _host(value)

    def __setattr__(self, name: str, value: Any) -> None:
        # A host array written back (``sim.done |= retreat``) goes to the device in the dtype it had.
        old: Any = getattr(self._core, name, None)
        if isinstance(value, np.ndarray) and type(old).__module__.startswith("torch"):
            value = self._core.xp.torch.as_tensor(value, dtype=old.dtype, device=old.device)
        setattr(self._core, name, value)


def _host(value: Any) -> Any:
    return HostCore(value) if isinstance(value, OvertakeCore) else to_host(value)


def host_core(core: OvertakeCore) -> Any:
    """``core`` itself on the numpy backend, else a :class:`HostCore` over it."""
    return core if core.xp.name == "numpy" else HostCore(core)


def make_core(config: Any = None, device: str | None = None, backend: str | None = None, **kwargs: Any) -> Any:
    """A core for a command's ``--device`` / ``--backend`` (:func:`~.backend.core_backend`), seen
    from the host: the numpy core by default, else a :class:`HostCore` over the torch core."""
    from overtakezoo.envs.backend import core_backend

    return host_core(OvertakeCore(config, **core_backend(device, backend), **kwargs))
