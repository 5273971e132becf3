"""Load a policy given on the command line or recorded by a leaderboard row, as a Decider.

Minimal form: a zoo registry name (``rule-fsm``) or ``package.module:factory`` (``factory(config=...)``
returns a Decider). Policy files (TorchScript, ONNX, Stable-Baselines3 zips) come with the full
loader; the name and signature of :func:`load_policy` stay.
"""

from __future__ import annotations

import importlib
import re
from typing import Any

from .errors import UserError

_FACTORY = re.compile(r"^[A-Za-z_][\w.]*:[A-Za-z_]\w*$")


def load_policy(spec: str, config: Any = None) -> Any:
    """A ready Decider for ``spec``; every failure is a UserError naming the spec."""
    from overtakezoo import zoo

    if spec in zoo.names():
        from .cmdutil import load_decider

        return load_decider(spec, config)
    if not _FACTORY.match(spec):
        raise UserError(f"policy {spec!r}: expected a zoo name ({', '.join(zoo.names())}) or package.module:factory")
    module_name, attr = spec.split(":")
    try:
        factory = getattr(importlib.import_module(module_name), attr)
    except ImportError as exc:
        raise UserError(f"policy {spec!r}: cannot import {module_name!r} ({exc})") from None
    except AttributeError:
        raise UserError(f"policy {spec!r}: module {module_name!r} has no {attr!r}") from None
    decider = factory(config=config)
    if not callable(getattr(decider, "act", None)):
        raise UserError(f"policy {spec!r}: the factory returned {type(decider).__name__}, which has no act(obs)")
    return decider
