"""Helpers shared by the benchmark subcommands in benchmark/commands/."""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path
from typing import Any

from overtakezoo.envs import ConfigError

from .errors import UserError


def add_parser(subparsers: Any, name: str, help: str, description: str, examples: list[str]) -> argparse.ArgumentParser:
    return subparsers.add_parser(
        name, help=help, description=description,
        epilog="examples:\n" + "\n".join(f"  {e}" for e in examples),
        formatter_class=argparse.RawDescriptionHelpFormatter)


def load_decider(name: str, config: Any = None) -> Any:
    from overtakezoo import zoo

    try:
        return zoo.load(name, config=config)
    except zoo.UnknownDecider as exc:
        raise UserError(str(exc)) from None
    except ConfigError as exc:
        raise UserError(f"decider {name!r}: {exc}") from None


def check_writable(path: str | Path) -> Path:
    """Fail before a long run, not after it, when ``path`` cannot be written."""
    path = Path(path)
    if path.is_dir():
        raise UserError(f"cannot write {path}: it is a directory")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".probe", dir=path.parent)
    except OSError as exc:
        raise UserError(f"cannot write {path}: {exc.strerror or exc}") from None
    os.close(fd)
    os.unlink(tmp)
    return path
