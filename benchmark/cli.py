"""The ``overtakezoo`` command line.

Each subcommand lives in its own module under ``benchmark/commands/`` exposing
``register(subparsers)``; modules are discovered, so adding a command touches no other file.
Bad input raises :class:`~overtakezoo.benchmark.errors.UserError`: one line on stderr, exit 2.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

from . import commands
from .errors import UserError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="overtakezoo",
        description="OvertakeZoo: a benchmark for abortable overtaking with oncoming traffic.",
        epilog="examples:\n  overtakezoo suites\n  overtakezoo eval --suite table1 --decider rule-fsm\n"
               "  overtakezoo COMMAND --help",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"{commands.__name__}.{info.name}")
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "handler", None):
        parser.print_help()
        return 2
    try:
        return int(args.handler(args) or 0)
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
