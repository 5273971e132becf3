"""Typed dataclasses from plain data: a trainer's hyperparameter schema, checked key by key.

A hyperparameter file is data the trainer trusts, so it is checked as the env's configuration is
(:mod:`overtakezoo.envs.config`): an unknown key (a misspelt ``gama``, with the nearest known key
suggested) or a value of the wrong type or out of range is one :class:`HyperparameterError` naming
the file and the key, never a key silently ignored or a crash deep in training. A schema is a plain
dataclass whose fields carry their range through :func:`param`::

    @dataclass(frozen=True)
    class DQNHyperparams:
        gamma: float = param(0.99, 0.0, 1.0)
        hidden: tuple[int, ...] = param((128, 128), 1, 4096)

    hp = build(DQNHyperparams, {"gamma": 0.95}, "where")   # files: contract.load_hyperparams

Supported field types: ``bool``, ``int``, ``float`` (an integer is accepted and converted), ``str``,
``tuple[int, ...]`` / ``tuple[float, ...]`` (a TOML array; the range applies to every element), a
nested schema dataclass (a TOML table, e.g. ppo's ``[train]``), ``dict[str, Any]`` (a free table
passed on as it is, e.g. the sections rsl-rl reads itself) and ``X | None``. A field without a
default is required. ``choices`` in :func:`param` limits a value to a set. Nothing of the builder is
specific to training: it is the project's one dict-to-dataclass builder, :mod:`overtakezoo.envs.typed`
(``EnvConfig.from_dict`` uses it too); this module names the trainers' error and stores an integer
given for a float as a float.
"""

from __future__ import annotations

from typing import Any, TypeVar

from overtakezoo.envs.config import ConfigError
from overtakezoo.envs.typed import as_dict as as_dict  # (re-exported: the card's plain data)
from overtakezoo.envs.typed import build as _build
from overtakezoo.envs.typed import param as param  # (re-exported: every trainer's schema declares its fields so)

T = TypeVar("T")


class HyperparameterError(ConfigError):
    """A hyperparameter file or mapping has an unknown key, a wrong type or an out-of-range value."""


def build(cls: type[T], data: Any, where: str, prefix: str = "") -> T:
    """Schema ``cls`` from a mapping; nested schemas are tables, named ``prefix.key`` in errors, each
    error a :class:`HyperparameterError` starting ``where: ``. An integer given for a float is stored
    as a float (what a card records)."""
    return _build(cls, data, error=HyperparameterError, where=where, prefix=prefix, coerce=True, root="hyperparameters")
