"""Reading JSON that came from outside (a pull request's leaderboard files, a downloaded registry, a
model or policy card, an archive's messages): bounded in size and nesting before it is parsed.

Python's decoder recurses once per level of nesting, so ``[[[[...]]]]`` a hundred thousand deep is a
``RecursionError`` (a traceback, not an ``error:`` line), and a file is read whole before it is parsed.
:func:`loads` checks the size, then the bracket depth with a cheap scan that skips strings, then
parses; :func:`load_file` reads at most the size cap. Both raise :class:`JSONInputError` (a
``ValueError``, so callers that wrap malformed input keep doing so; the CLI prints it as one
``error:`` line) naming the file. Files the project writes itself and reads back need none of this.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

# The deepest JSON the project reads or writes nests 12 levels (the results schema; a results row or a
# card: 3-7); the decoder's recursion limit is ~1000 levels away from that.
MAX_JSON_DEPTH = 64
# The largest JSON read from outside is a results row (~0.4 MB for the platoon suite's 2000 scenarios);
# 64 MiB leaves room for far larger suites while bounding what is read into memory.
MAX_JSON_BYTES = 64 << 20

# A JSON string (escapes included), replaced by "" before brackets are counted: brackets in strings do not nest.
_STRING = re.compile(rb'"[^"\\]*(?:\\.[^"\\]*)*"', re.DOTALL)


class JSONInputError(ValueError):
    """JSON from outside that is too large, nested too deep or malformed (``str``: one line naming the
    file; ``reason``: the same without the name)."""

    def __init__(self, where: str, reason: str) -> None:
        super().__init__(f"{where}: {reason}")
        self.reason = reason


def depth(data: bytes) -> int:
    """The deepest nesting of arrays and objects in the JSON text ``data`` (brackets inside strings skipped)."""
    if data.count(b"[") + data.count(b"{") <= MAX_JSON_DEPTH:
        return data.count(b"[") + data.count(b"{")  # an upper bound, and small: nothing to scan
    text = np.frombuffer(_STRING.sub(b'""', data), np.uint8)
    step = np.isin(text, (ord("["), ord("{"))).astype(np.int64) - np.isin(text, (ord("]"), ord("}"))).astype(np.int64)
    return int(np.cumsum(step).max(initial=0))


def loads(
    data: bytes | str, where: str, *, max_bytes: int = MAX_JSON_BYTES, max_depth: int = MAX_JSON_DEPTH, **kwargs: Any
) -> Any:
    """``json.loads(data, **kwargs)`` once ``data`` is at most ``max_bytes`` long and nests at most
    ``max_depth`` deep; :class:`JSONInputError` naming ``where`` otherwise, or when it is not JSON.
    Errors raised by ``kwargs``' hooks pass through unchanged."""
    raw = data.encode("utf-8", "surrogatepass") if isinstance(data, str) else bytes(data)
    if len(raw) > max_bytes:
        raise JSONInputError(where, f"more than {max_bytes} bytes of JSON (the most read from a file)")
    deep = depth(raw)
    if deep > max_depth:
        raise JSONInputError(where, f"JSON nested {deep} levels deep, at most {max_depth}")
    try:
        return json.loads(data, **kwargs)
    except UnicodeDecodeError as exc:
        raise JSONInputError(where, f"not JSON (not UTF-8: {exc.reason} at byte {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise JSONInputError(where, f"not JSON ({exc.msg}: line {exc.lineno} column {exc.colno})") from None
    except RecursionError:  # (the depth scan keeps this from happening)
        raise JSONInputError(where, "JSON nested too deep") from None


def read_bounded(path: str | os.PathLike, max_bytes: int = MAX_JSON_BYTES) -> bytes:
    """At most ``max_bytes`` + 1 bytes of the file ``path`` (one more than the cap: enough to tell it is
    larger); ``OSError`` as ``open`` raises it."""
    with open(path, "rb") as f:
        return f.read(max_bytes + 1)


def load_file(
    path: str | os.PathLike,
    where: str | None = None,
    *,
    max_bytes: int = MAX_JSON_BYTES,
    max_depth: int = MAX_JSON_DEPTH,
    **kwargs: Any,
) -> Any:
    """The JSON in the file ``path``, read and parsed within the caps (:func:`loads`); ``where``
    (default: the path) names it in errors. ``OSError`` passes through."""
    data = read_bounded(path, max_bytes)
    return loads(data, str(Path(path)) if where is None else where, max_bytes=max_bytes, max_depth=max_depth, **kwargs)
