"""Quotes: a documentation page names a measured number by where it is stored, and the site build
(``tools/mkdocs_hooks.py``) writes the number in. A page never types a measured number by hand, so
it cannot drift from the file a command wrote (``tests/docs/test_doc_numbers.py`` checks both).

A quote is ``{{ FILE PATH }}`` or ``{{ FILE PATH | FORMAT }}``:

- ``FILE``: a JSON or TOML file written by a command or pinned by the benchmark, repository-relative,
  under one of :data:`SOURCES` (the generated reports in ``docs/``, the leaderboard, the model cards,
  the suites and the hyperparameters);
- ``PATH``: keys joined by ``/``; ``name[key=value]`` picks the element of the list ``name`` whose
  ``key`` is ``value``; a number picks a list element by index;
- ``FORMAT``: a Python format spec (``.1f``, ``,``, ``,.0f``), or ``pct`` / ``pct0`` (a rate written
  as a percentage with one or no decimal: 0.9713 -> ``97.1``); without it the value as stored.

``{{ leaderboards/index.json headline/scores/dqn/value | pct }}`` is dqn's score; ``{{
docs/perf-training.json figures[id=time-to-paper-level]/median | .2f }}`` the numpy PPO's time to
the paper's level. Written by hand rather than with mkdocs-macros: that plugin renders pages as
Jinja templates, and the leaderboard's pages carry text from pull requests, where a template is code
run by the docs build; a quote here can only read a value from a listed file.
"""

from __future__ import annotations

import json
import re
import tomllib
from functools import cache
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ("docs/", "leaderboards/", "zoo/pretrained/", "zoo/hyperparams/", "envs/suites/")
QUOTE = re.compile(r"\{\{\s*(?P<file>[\w./+-]+\.(?:json|toml))\s+(?P<path>[^|}]*?)\s*(?:\|\s*(?P<fmt>[^}]*?)\s*)?\}\}")
_PICK = re.compile(r"^(?P<name>[^\[\]]*)\[(?P<key>[\w-]+)=(?P<value>[^\]]*)\]$")


class QuoteError(ValueError):
    """A quote that names no file, no value or no format: the build stops with its text."""


@cache
def _load(file: str, root: Path) -> Any:
    if ".." in Path(file).parts or not file.startswith(SOURCES):
        raise QuoteError(f"{file}: quotes read only files under {', '.join(SOURCES)}")
    path = root / file
    try:
        text = path.read_text("utf-8")
    except OSError as exc:
        raise QuoteError(f"{file}: {exc.strerror or exc}") from None
    return tomllib.loads(text) if file.endswith(".toml") else json.loads(text)


def _step(value: Any, part: str, where: str) -> Any:
    pick = _PICK.match(part)
    if pick:
        items = value.get(pick["name"]) if pick["name"] else value
        if not isinstance(items, list):
            raise QuoteError(f"{where}: {pick['name']!r} is not a list")
        found = [x for x in items if isinstance(x, dict) and str(x.get(pick["key"])) == pick["value"]]
        if len(found) != 1:
            raise QuoteError(f"{where}: {len(found)} elements of {pick['name']!r} have {pick['key']} = {pick['value']}")
        return found[0]
    if isinstance(value, list) and part.isdigit() and int(part) < len(value):
        return value[int(part)]
    if isinstance(value, dict) and part in value:
        return value[part]
    raise QuoteError(f"{where}: no {part!r}")


def _format(value: Any, fmt: str | None, where: str) -> str:
    if isinstance(value, (dict, list)) or value is None:
        raise QuoteError(f"{where}: not a number or a string ({type(value).__name__})")
    if not fmt:
        return str(value)
    if fmt in ("pct", "pct0"):
        if not isinstance(value, (int, float)):
            raise QuoteError(f"{where}: {fmt} needs a number")
        return f"{100 * value:.{1 if fmt == 'pct' else 0}f}"
    try:
        return format(value, fmt)
    except (TypeError, ValueError) as exc:
        raise QuoteError(f"{where}: format {fmt!r}: {exc}") from None


def value(file: str, path: str, fmt: str | None = None, root: Path = ROOT) -> str:
    """The text of one quote."""
    where = f"{{{{ {file} {path}{f' | {fmt}' if fmt else ''} }}}}"
    found = _load(file, root)
    for part in filter(None, path.split("/")):
        found = _step(found, part, where)
    return _format(found, fmt, where)


def expand(text: str, root: Path = ROOT) -> str:
    """``text`` with every quote replaced by its value (a :class:`QuoteError` names a bad one)."""
    return QUOTE.sub(lambda m: value(m["file"], m["path"], m["fmt"], root), text)
