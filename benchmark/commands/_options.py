"""Options shared by the benchmark subcommands in benchmark/commands/ (not a command itself)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any

# The checkout this package runs from (an editable install): benchmark/commands/ -> the repository root.
CHECKOUT_LEADERBOARDS = Path(__file__).resolve().parents[2] / "leaderboards"

DEFAULT_ROOT_RULE = (
    "without --root: ./leaderboards where it has a submissions/ folder, else the leaderboards/ "
    "of the checkout this package runs from, else an error (the default never creates a folder)"
)


def root_help(new_ok: bool = False) -> str:
    """The ``--root`` help of every leaderboard command (submit, leaderboard): one rule, said the same way."""
    given = (
        "PATH, created when nothing is there yet (a new leaderboard)"
        if new_ok
        else "PATH, which must exist (else: no such folder: PATH)"
    )
    return f"the leaderboard folder, found by one rule for submit and leaderboard: {given}; {DEFAULT_ROOT_RULE}"


def leaderboard_root(root: str | None, new_ok: bool = False) -> str:
    """The one rule ``submit``, ``leaderboard``, ``leaderboard --check`` and ``leaderboard --verify``
    find their leaderboard by. ``root`` when given: a folder that exists, else a UserError
    "no such folder: PATH" (with ``new_ok``, submit's explicit --root, a path where nothing is yet is
    returned to be created). Without it: ``./leaderboards`` where it has ``submissions/``, else the
    checkout's own ``leaderboards/`` (an editable install run from another folder), else a UserError:
    the default never names a fresh, empty folder (one that --check would call stale, or that submit
    would start a stray board in)."""
    from overtakezoo.benchmark.errors import UserError

    if root is not None:
        path = Path(root)
        if path.is_dir() or path.is_symlink():  # a symlinked root is refused by name later (check_tree)
            return root
        if new_ok and not path.exists() and not path.is_symlink():
            above = next(p for p in path.absolute().parents if p.exists())  # what the new folders go under
            if not above.is_dir() or not os.access(above, os.W_OK | os.X_OK):
                raise UserError(f"cannot write {root}: {above} is not a writable folder")
            return root
        raise UserError(f"no such folder: {root}" + (" (a file is there)" if path.exists() else ""))
    for candidate in (Path("leaderboards"), CHECKOUT_LEADERBOARDS):
        if (candidate / "submissions").is_dir():
            return str(candidate)
    raise UserError(
        "no leaderboard here: neither ./leaderboards nor this package's checkout has a "
        "leaderboards/submissions/ folder; run from the repository root or pass --root"
    )


def add_parser(subparsers: Any, name: str, help: str, description: str, examples: list[str]) -> argparse.ArgumentParser:
    return subparsers.add_parser(
        name,
        help=help,
        description=description,
        epilog="examples:\n" + "\n".join(f"  {e}" for e in examples),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )


def add_decider_options(p: argparse.ArgumentParser) -> None:
    """``--decider NAME`` or ``--policy SPEC`` (one of them)."""
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--decider", help="a decider name from the zoo registry (see `overtakezoo zoo`)")
    g.add_argument(
        "--policy",
        metavar="SPEC",
        help="any policy: a zoo name, package.module:factory (your code, run in this process), or a "
        "file, read as data and run in a sandboxed child process: weights written by `overtakezoo "
        "train` (<algo>.npz or .pt beside <algo>.json), an ONNX file ([onnx] extra; external data "
        "inlined from beside it), a Stable-Baselines3 .zip (DQN/PPO/A2C MlpPolicy; its state dict "
        "is read with weights_only and its pickled entries are never unpickled) or a TorchScript "
        "file (deprecated by torch)",
    )
    p.add_argument(
        "--shield",
        action="store_true",
        help="put the decider behind the RSS shield (zoo/members/shield.py): "
        "an overtake that cannot keep the RSS distance to the oncoming traffic it sees is vetoed or "
        "aborted (as --decider shielded:NAME)",
    )


def add_device_options(p: argparse.ArgumentParser, what: str = "the simulation") -> None:
    """``--device`` / ``--backend``: where the core runs (envs/backend.py ``core_backend``)."""
    p.add_argument(
        "--device",
        default="cpu",
        metavar="DEV",
        help=f"where {what} runs: cpu (the numpy core, the default) or cuda / cuda:N (the torch core on "
        "that GPU, float64: the same per-scenario results as the CPU, so its rows verify anywhere)",
    )
    p.add_argument(
        "--backend",
        choices=("numpy", "torch"),
        default=None,
        help="the core's array library (default: numpy on cpu, torch on cuda); --backend torch "
        "--device cpu runs the GPU path on the CPU",
    )


def device_from_args(args: argparse.Namespace) -> dict[str, Any]:
    """The core's ``backend`` / ``device`` keywords from ``--device`` / ``--backend``; a device that is
    not there is a UserError."""
    from overtakezoo.benchmark.errors import UserError
    from overtakezoo.envs.backend import core_backend

    try:
        return core_backend(args.device, args.backend)
    except ValueError as exc:
        raise UserError(str(exc)) from None


def decider_from_args(args: argparse.Namespace, config: Any = None) -> Any:
    if args.policy is not None:
        from overtakezoo.benchmark.run.policy import load_policy

        decider = load_policy(args.policy, config)
    else:
        from overtakezoo.benchmark.run.policy import load_zoo

        decider = load_zoo(args.decider, config)
    if getattr(args, "shield", False):
        from overtakezoo.zoo.members.shield import Shielded

        decider = Shielded(decider)
    return decider
