"""Gymnasium version shims: the package runs on gymnasium 1.0.x (d3rlpy 2.8 pins ``gymnasium==1.0.0``)
as well as 1.1+.

``gymnasium.vector.AutoresetMode`` is new in gymnasium 1.1; 1.0's vector envs autoreset only the
next-step way and have no enum for it. Where it is missing, :class:`AutoresetMode` here is an Enum with
gymnasium 1.1's member names and values, so ``autoreset_mode="SameStep"`` / ``AutoresetMode.SAME_STEP``
and ``metadata["autoreset_mode"]`` read the same on both. On 1.0 our own vector env still honours
SAME_STEP; only gymnasium's own wrappers and vector envs know nothing of the mode.
"""

from __future__ import annotations

from enum import Enum

try:
    from gymnasium.vector import AutoresetMode

    HAS_AUTORESET_MODE = True
except ImportError:  # gymnasium 1.0.x
    HAS_AUTORESET_MODE = False

    class AutoresetMode(Enum):  # type: ignore[no-redef]
        """gymnasium 1.1's ``gymnasium.vector.AutoresetMode`` (same names and values), for gymnasium 1.0."""

        NEXT_STEP = "NextStep"
        SAME_STEP = "SameStep"
        DISABLED = "Disabled"


__all__ = ["AutoresetMode", "HAS_AUTORESET_MODE"]
