"""Helpers shared by the benchmark subcommands in benchmark/commands/."""

from __future__ import annotations

import argparse
from typing import Any

from overtakezoo.envs import ConfigError

from .errors import UserError
from .io import check_writable, check_writable_dir  # noqa: F401 - re-exported for the commands


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
