"""render() / close() shared by the Gymnasium and PettingZoo faces: both show row 0 of their core.
matplotlib is imported on the first render only."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from overtakezoo.envs.core import OvertakeCore


class RendersFirstRow:
    """Mixin: needs ``self.core``, ``self.render_mode`` and ``self.metadata["render_fps"]``."""

    core: OvertakeCore
    render_mode: str | None
    metadata: dict[str, Any]
    _renderer: Any = None

    def _render_first_row(self) -> Any:
        from overtakezoo.envs.faces.render import Renderer, frame_from_core

        if self._renderer is None:
            assert self.render_mode is not None  # (render() returns before this without a render_mode)
            self._renderer = Renderer(self.render_mode, fps=self.metadata["render_fps"])
        return self._renderer.render(frame_from_core(self.core, 0))

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
