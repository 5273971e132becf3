"""A sync-free core step with fixed state buffers, for capture in a CUDA graph.

A captured graph replays the kernels of one step on the same memory. The core's step reads its
state tensors and binds the results to new tensors; :class:`StaticStep` copies every result back
into the tensor it replaces, so every step reads and writes the same buffers and a replay of the
captured step is the next step. Eagerly (no graph; e.g. on the CPU, where this is tested) it is an
ordinary step plus those copies.
"""

from __future__ import annotations

from typing import Any

from overtakezoo.envs.core import OvertakeCore

_STATE_DICTS = ("stats", "_ego", "_npc")


class StaticStep:
    """``step()`` advances ``core`` (torch backend, sync-free, reset, auto-reset from a bank if it
    resets) under ``modes`` (a fixed (B,) tensor: write new modes into it), keeping every state
    tensor in place. ``compile`` fuses the step with ``torch.compile`` (one graph, no break: the
    step has no data-dependent branch; the first steps compile, about half a minute).
    ``capture()`` records one step in a CUDA graph; ``step()`` then replays it."""

    def __init__(self, core: OvertakeCore, modes: Any, warmup: int = 3, compile: bool = False) -> None:
        if core.xp.name != "torch" or not core.xp.sync_free:
            raise ValueError("StaticStep needs a sync-free torch core (OvertakeCore(backend='torch', sync_free=True))")
        if core.auto_reset and core.bank is None:
            raise ValueError("StaticStep: an auto-reset core must reset from a bank (OvertakeCore(bank=...))")
        self.core, self.modes = core, modes
        self.graph: Any = None
        self.result: Any = None
        for _ in range(warmup):  # the step's Python branches settle (e.g. the first plan exists)
            self._eager()
        import torch

        self._fn = torch.compile(self._eager, fullgraph=True, dynamic=False) if compile else self._eager
        if compile:
            self._fn()  # (compiles now, not inside a capture)

    def _buffers(self) -> dict[tuple[str, str | None], Any]:
        import torch

        out: dict[tuple[str, str | None], Any] = {}
        for name, value in vars(self.core).items():
            if isinstance(value, torch.Tensor):
                out[(name, None)] = value
            elif name in _STATE_DICTS:
                out.update({(name, key): v for key, v in value.items() if isinstance(v, torch.Tensor)})
        return out

    def _eager(self) -> Any:
        before = self._buffers()
        self.result = self.core.step(self.modes)
        core = self.core
        for (name, key), old in before.items():
            new = getattr(core, name) if key is None else getattr(core, name)[key]
            if new is not old:
                old.copy_(new)
                if key is None:
                    setattr(core, name, old)
                else:
                    getattr(core, name)[key] = old
        return self.result

    def capture(self) -> None:
        """Record one step in a CUDA graph (the core must be on a CUDA device)."""
        import torch

        stream = torch.cuda.Stream()
        stream.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(stream):
            self._fn()  # (a step on the side stream before capture, as torch's docs advise)
        torch.cuda.current_stream().wait_stream(stream)
        graph = self.graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph):
            self._fn()

    def step(self) -> Any:
        """One step; its StepResult's tensors are rewritten by the next step (copy what you keep)."""
        if self.graph is None:
            return self._fn()
        self.graph.replay()
        return self.result
