"""Typed, frozen dataclasses from plain (TOML) data: the project's one dict-to-dataclass builder.

A schema is a dataclass whose fields carry their range in their metadata: :func:`bounded` (the env's
settings, ``envs/config.py``: positional, with a unit) or :func:`param` (a trainer's hyperparameters,
``zoo/train/typed.py``: keyword-only, optionally required, with ``choices``). :func:`build` makes
one from a nested mapping, key by key: an unknown key (with the nearest known one suggested), a
value of the wrong type or out of range is one error naming the key's full path (``planner.max_steer``,
``train.steps``), never a key silently ignored or a crash deep in a run.

Supported field types: ``bool``, ``int`` (``2.0`` is refused, not rounded), ``float``, ``str``,
``tuple[X, ...]`` (an array; the range applies to every element), a nested schema (a table),
``dict[str, Schema]`` (a table of schemas: its keys are the default's, each entry given key by key
over the default's entry, e.g. the planner's ``modes``), ``dict[str, Any]`` (a free table, passed on
as it is) and ``X | None``. A field without a default is required.

Nothing here names its error class: the env raises ``ConfigError`` (``envs/config.py``), the trainers
``HyperparameterError`` (``zoo/train/typed.py``), each through :func:`build`'s ``error``.
"""

from __future__ import annotations

import dataclasses
import difflib
import numbers
import types
import typing
from collections.abc import Iterable, Mapping
from typing import Any, TypeVar

import numpy as np

T = TypeVar("T")


def unknown_key(key: Any, known: Iterable[Any]) -> str:
    """'unknown key' with the nearest known name, if one is close (a misspelling), and the list."""
    known = list(known)
    close = difflib.get_close_matches(str(key), [str(k) for k in known], n=1, cutoff=0.75)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    return f"unknown key{hint}; known: {', '.join(sorted(map(str, known)))}"


def bounded(default: Any, lo: float, hi: float, unit: str = "") -> Any:
    """A setting with its physical range [lo, hi] (for a [low, high] pair: both ends), kept in the
    field's metadata so the check, the error message and the docs quote one range. Integer
    defaults make integer settings."""
    integer = isinstance(default, int) and not isinstance(default, bool)
    return dataclasses.field(default=default, metadata={"lo": lo, "hi": hi, "unit": unit, "integer": integer})


def param(
    default: Any = dataclasses.MISSING,
    lo: float | None = None,
    hi: float | None = None,
    *,
    choices: tuple[Any, ...] | None = None,
) -> Any:
    """A keyword-only schema field: its default (none: required), the closed range [lo, hi] of a
    number (or of every element of a tuple) and the allowed ``choices``."""
    meta = {"lo": lo, "hi": hi, "choices": choices}
    # Keyword-only, so a required field may follow optional ones in the class body.
    if isinstance(default, (list, dict)):  # mutable defaults go through a factory
        value = default
        return dataclasses.field(default_factory=lambda: type(value)(value), metadata=meta, kw_only=True)
    return dataclasses.field(default=default, metadata=meta, kw_only=True)


def number_problem(value: Any, lo: float | None, hi: float | None, integer: bool = False, unit: str = "") -> str | None:
    """Why ``value`` is no number (an integer where ``integer``) in [lo, hi] (None: unbounded), or None."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        return f"expected {'an integer' if integer else 'a number'}, got {value!r}"
    # Counts and indices must be integers: 2.0 is refused (not rounded) so a typo cannot pass silently.
    if integer and not isinstance(value, numbers.Integral):
        return f"expected an integer, got {value!r}"
    # (Compared before any conversion: a huge integer is out of range, not an OverflowError; NaN never in range.)
    x: Any = value
    if (lo is not None and not lo <= x) or (hi is not None and not x <= hi) or x != x:
        low, high = ("-inf" if lo is None else lo), ("inf" if hi is None else hi)
        return f"{value!r} is out of range [{low}, {high}]" + (f" {unit}" if unit else "")
    return None


def bool_problem(value: Any) -> str | None:
    """Why ``value`` is not true or false (a numpy bool is), or None."""
    return None if isinstance(value, (bool, np.bool_)) else f"expected true or false, got {value!r}"


def check_ranges(obj: Any, prefix: str, error: type[Exception], skip: tuple[str, ...] = ()) -> None:
    """Every ranged field (:func:`bounded`, :func:`param` with a range) of dataclass ``obj`` inside
    its range: ``error`` naming ``prefix + field`` otherwise."""
    for f in dataclasses.fields(obj):
        meta = f.metadata
        if "lo" not in meta or f.name in skip:
            continue
        value = getattr(obj, f.name)
        for v in value if isinstance(value, tuple) else (value,):
            why = number_problem(v, meta["lo"], meta["hi"], meta.get("integer", False), meta.get("unit", ""))
            if why:
                raise error(f"{prefix}{f.name}: {why}")


_SCHEMAS: dict[type, dict[str, tuple[dataclasses.Field[Any], Any]]] = {}


def _schema(cls: type) -> dict[str, tuple[dataclasses.Field[Any], Any]]:
    """Each field of schema ``cls`` with its resolved type (read once per class)."""
    if cls not in _SCHEMAS:
        hints = typing.get_type_hints(cls)
        _SCHEMAS[cls] = {f.name: (f, hints[f.name]) for f in dataclasses.fields(cls)}
    return _SCHEMAS[cls]


@dataclasses.dataclass(frozen=True)
class _Reader:
    error: type[Exception]
    where: str  # "" or what the data is ("zoo/hyperparams/dqn.toml"), put before every key
    coerce: bool  # an int given for a float field is stored as a float (else as given)
    root: str  # the name of the whole table in an error about it

    def fail(self, key: str, why: str) -> Exception:
        return self.error(f"{self.where}: {key or self.root}: {why}" if self.where else f"{key or self.root}: {why}")

    def build(self, cls: type[T], data: Any, prefix: str, base: Any = None) -> T:
        if isinstance(data, cls):
            return data
        if not isinstance(data, Mapping):
            raise self.fail(prefix.rstrip("."), f"expected a table, got {data!r}")
        schema = _schema(cls)
        for key in data:
            if key not in schema:
                raise self.fail(f"{prefix}{key}", unknown_key(key, schema))
        kwargs = {}
        for name, (f, tp) in schema.items():
            if name in data:
                kwargs[name] = self.value(tp, data[name], f, f"{prefix}{name}")
            elif base is not None:  # an entry given key by key over its default (dict[str, Schema])
                kwargs[name] = getattr(base, name)
            elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise self.fail(f"{prefix}{name}", "missing (required)")
        try:
            return cls(**kwargs)
        except TypeError as exc:  # a wrong type reaching a schema's own checks
            raise self.fail(prefix.rstrip("."), str(exc)) from None

    def value(self, tp: Any, value: Any, f: dataclasses.Field[Any], key: str) -> Any:
        meta = f.metadata
        origin, args = typing.get_origin(tp), typing.get_args(tp)
        if origin in (typing.Union, types.UnionType):  # X | None
            if value is None and type(None) in args:
                return None
            (tp,) = [a for a in args if a is not type(None)]
            origin, args = typing.get_origin(tp), typing.get_args(tp)
        choices = meta.get("choices")
        if choices is not None and value not in choices:
            raise self.fail(key, f"{value!r} is not one of {', '.join(map(repr, choices))}")
        if _is_schema(tp):
            return self.build(tp, value, f"{key}.")
        if origin is dict or tp is dict:
            if not isinstance(value, Mapping):
                raise self.fail(key, f"expected a table, got {value!r}")
            if len(args) == 2 and _is_schema(args[1]):
                return self.table_of(args[1], value, f, key)
            return dict(value)
        if origin is tuple:
            if not isinstance(value, (list, tuple)):
                raise self.fail(key, f"expected an array, got {value!r}")
            return tuple(self.scalar(args[0], v, meta, f"{key}[{i}]") for i, v in enumerate(value))
        return self.scalar(tp, value, meta, key)

    def table_of(self, schema: type, value: Mapping[str, Any], f: dataclasses.Field[Any], key: str) -> dict[str, Any]:
        """A table of ``schema`` entries: the field's default's keys, each entry over the default's."""
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else {}
        out = dict(default)
        for name, entry in value.items():
            if default and name not in default:
                raise self.fail(f"{key}.{name}", unknown_key(name, default))
            out[name] = self.build(schema, entry, f"{key}.{name}.", default.get(name))
        return out

    def scalar(self, tp: Any, value: Any, meta: Mapping[str, Any], key: str) -> Any:
        if tp is bool:
            why = bool_problem(value)
        elif tp is str:
            why = None if isinstance(value, str) else f"expected a string, got {value!r}"
        elif tp in (int, float):
            lo, hi = meta.get("lo"), meta.get("hi")
            why = number_problem(value, lo, hi, tp is int, meta.get("unit", ""))
            if why is None and self.coerce:
                value = tp(value)
        elif tp is Any:
            why = None
        else:
            raise TypeError(f"schema field {key}: unsupported type {tp!r}")
        if why:
            raise self.fail(key, why)
        return value


def _is_schema(tp: Any) -> bool:
    return isinstance(tp, type) and dataclasses.is_dataclass(tp)


def build(
    cls: type[T],
    data: Any,
    *,
    error: type[Exception],
    where: str = "",
    prefix: str = "",
    coerce: bool = False,
    root: str = "config",
) -> T:
    """Schema ``cls`` from a (nested) mapping, checked key by key; every problem is one ``error``
    naming ``where: prefix.key`` (``root`` for the whole table). ``coerce``: an integer given for a
    float field is stored as a float (the trainers'); else values are stored as given (the env's, so
    a stored configuration reads back as it was written). An instance of ``cls`` is returned as is."""
    return _Reader(error, where, coerce, root).build(cls, data, prefix)


def as_dict(obj: Any) -> dict[str, Any]:
    """A schema instance as plain data (tuples as lists): what a model card or checkpoint stores."""

    def plain(v: Any) -> Any:
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            return as_dict(v)
        if isinstance(v, tuple):
            return [plain(x) for x in v]
        if isinstance(v, dict):
            return {k: plain(x) for k, x in v.items()}
        return v

    return {f.name: plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
