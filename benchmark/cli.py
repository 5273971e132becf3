"""The ``overtakezoo`` command line.

Each subcommand lives in its own module under ``benchmark/commands/`` exposing
``register(subparsers)``; modules are discovered, so adding a command touches no other file
(``_options.py`` holds the options they share).
Bad input raises :class:`~overtakezoo.benchmark.errors.UserError` (or, from the layers below, a
``ConfigError`` or an unwritable path's ``WriteError``): one line on stderr, exit 2. SIGTERM is raised
like Ctrl-C so cleanup runs and no half-written file is left; a closed stdout pipe ends quietly.
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import signal
import sys
import threading

from overtakezoo.benchmark import commands
from overtakezoo.benchmark.errors import UserError, one_line
from overtakezoo.envs import ConfigError
from overtakezoo.envs.io import WriteError
from overtakezoo.envs.safe_json import JSONInputError


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised like Ctrl-C so ``finally`` blocks run and temp files are removed."""


def _on_sigterm(signum: int, frame: object) -> None:
    raise Terminated()


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
        if info.name.startswith("_"):  # shared option helpers (_options.py), not a command
            continue
        module = importlib.import_module(f"{commands.__name__}.{info.name}")
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "handler", None):
        parser.print_help()
        return 2
    in_main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _on_sigterm) if in_main_thread else None
    try:
        return _run(args)
    finally:
        if in_main_thread:
            signal.signal(signal.SIGTERM, previous)


def _run(args: argparse.Namespace) -> int:
    try:
        code = int(args.handler(args) or 0)
        sys.stdout.flush()  # a reader that went away shows here, not as a traceback at exit
        return code
    except BrokenPipeError:
        # `overtakezoo replay run.mcap --list | head`: the recipe of Python's signal docs (note on
        # SIGPIPE): point stdout at devnull so the final flush cannot fail again, exit 1 quietly.
        try:
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        except (OSError, ValueError, AttributeError):  # stdout without a file descriptor (captured)
            pass
        return 1
    except (UserError, ConfigError, WriteError, JSONInputError) as exc:
        print(f"error: {one_line(exc)}", file=sys.stderr)  # control characters from a file name or value escaped
        return 2
    except Terminated:
        print("terminated", file=sys.stderr)
        return 143
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
