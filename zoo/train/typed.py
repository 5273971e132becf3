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
default is required. ``choices`` in :func:`param` limits a value to a set. Nothing here is specific
to training: it is the most complete of the project's dict-to-dataclass readers (``envs/config.py``
and ``envs/scenarios.py`` have their own).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import types
import typing
from collections.abc import Mapping
from typing import Any, TypeVar

from overtakezoo.envs.config import ConfigError, unknown_key

T = TypeVar("T")


class HyperparameterError(ConfigError):
    """A hyperparameter file or mapping has an unknown key, a wrong type or an out-of-range value."""


def param(
    default: Any = dataclasses.MISSING,
    lo: float | None = None,
    hi: float | None = None,
    *,
    choices: tuple[Any, ...] | None = None,
) -> Any:
    """A schema field: its default (none: required), the closed range [lo, hi] of a number (or of
    every element of a tuple) and the allowed ``choices``."""
    meta = {"lo": lo, "hi": hi, "choices": choices}
    # Keyword-only, so a required field may follow optional ones in the class body.
    if isinstance(default, (list, dict)):  # mutable defaults go through a factory
        value = default
        return dataclasses.field(default_factory=lambda: type(value)(value), metadata=meta, kw_only=True)
    return dataclasses.field(default=default, metadata=meta, kw_only=True)


def build(cls: type[T], data: Any, where: str, prefix: str = "") -> T:
    """Schema ``cls`` from a mapping; nested schemas are tables, named ``prefix.key`` in errors."""
    if not isinstance(data, Mapping):
        raise HyperparameterError(f"{where}: {prefix.rstrip('.') or 'hyperparameters'}: expected a table, got {data!r}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    for key in data:
        if key not in fields:
            raise HyperparameterError(f"{where}: {prefix}{key}: {unknown_key(key, fields)}")
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for name, f in fields.items():
        if name in data:
            kwargs[name] = _value(hints[name], data[name], f.metadata, where, f"{prefix}{name}")
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise HyperparameterError(f"{where}: {prefix}{name}: missing (required)")
    return cls(**kwargs)


def _value(tp: Any, value: Any, meta: Mapping[str, Any], where: str, key: str) -> Any:
    def fail(why: str) -> HyperparameterError:
        return HyperparameterError(f"{where}: {key}: {why}")

    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):  # X | None
        if value is None and type(None) in args:
            return None
        (tp,) = [a for a in args if a is not type(None)]
        origin, args = typing.get_origin(tp), typing.get_args(tp)
    if dataclasses.is_dataclass(tp):
        return build(tp, value, where, f"{key}.")
    if origin is dict or tp is dict:
        if not isinstance(value, Mapping):
            raise fail(f"expected a table, got {value!r}")
        return dict(value)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise fail(f"expected an array, got {value!r}")
        return tuple(_value(args[0], v, meta, where, f"{key}[{i}]") for i, v in enumerate(value))
    if tp is bool:
        if not isinstance(value, bool):
            raise fail(f"expected true or false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise fail(f"expected a string, got {value!r}")
    elif tp in (int, float):
        # Counts must be integers: 2.0 is refused (not rounded), so a typo cannot pass silently.
        if (
            isinstance(value, bool)
            or not isinstance(value, numbers.Real)
            or (tp is int and not isinstance(value, numbers.Integral))
        ):
            raise fail(f"expected {'an integer' if tp is int else 'a number'}, got {value!r}")
        given, value = value, tp(value)
        lo, hi = meta.get("lo"), meta.get("hi")
        if math.isnan(value) or (lo is not None and value < lo) or (hi is not None and value > hi):
            raise fail(
                f"{given!r} is out of range [{lo if lo is not None else '-inf'}, {hi if hi is not None else 'inf'}]"
            )
    else:
        raise TypeError(f"schema field {key}: unsupported type {tp!r}")
    choices = meta.get("choices")
    if choices is not None and value not in choices:
        raise fail(f"{value!r} is not one of {', '.join(map(repr, choices))}")
    return value


def as_dict(hp: Any) -> dict[str, Any]:
    """A schema instance as plain data (tuples as lists): what a model card or checkpoint stores."""

    def plain(v: Any) -> Any:
        if isinstance(v, tuple):
            return [plain(x) for x in v]
        if isinstance(v, dict):
            return {k: plain(x) for k, x in v.items()}
        return v

    return {
        f.name: plain(getattr(hp, f.name))
        if not dataclasses.is_dataclass(getattr(hp, f.name))
        else as_dict(getattr(hp, f.name))
        for f in dataclasses.fields(hp)
    }
