"""render() / close() shared by the Gymnasium and PettingZoo faces: both show row 0 of their core.
matplotlib is imported on the first render only."""

from __future__ import annotations

from typing import Any


class RendersFirstRow:
    """Mixin: needs ``self.core``, ``self.render_mode`` and ``self.metadata["render_fps"]``."""

    _renderer: Any = None

    def _render_first_row(self) -> Any:
        from overtakezoo.envs.faces.render import Renderer, frame_from_core

        if self._renderer is None:
            self._renderer = Renderer(self.render_mode, fps=self.metadata["render_fps"])
        return self._renderer.render(frame_from_core(self.core, 0))

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
