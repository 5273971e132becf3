"""Options shared by the benchmark subcommands in benchmark/commands/ (not a command itself)."""

from __future__ import annotations

import argparse
from typing import Any



def add_parser(subparsers: Any, name: str, help: str, description: str, examples: list[str]) -> argparse.ArgumentParser:
    return subparsers.add_parser(
        name, help=help, description=description,
        epilog="examples:\n" + "\n".join(f"  {e}" for e in examples),
        formatter_class=argparse.RawDescriptionHelpFormatter)


def add_decider_options(p: argparse.ArgumentParser) -> None:
    """``--decider NAME`` or ``--policy SPEC`` (one of them)."""
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--decider", help="a decider name from the zoo registry (see `overtakezoo zoo`)")
    g.add_argument("--policy", metavar="SPEC",
                   help="any policy: a zoo name, package.module:factory (your code, run in this process), or a "
                        "file, read as data and run in a sandboxed child process: weights written by `overtakezoo "
                        "train` (<algo>.npz or .pt beside <algo>.json), an ONNX file ([onnx] extra; external data "
                        "inlined from beside it), a Stable-Baselines3 .zip (DQN/PPO/A2C MlpPolicy; its state dict "
                        "is read with weights_only and its pickled entries are never unpickled) or a TorchScript "
                        "file (deprecated by torch)")
    p.add_argument("--shield", action="store_true", help="put the decider behind the RSS shield (zoo/members/shield.py): "
                   "an overtake that cannot keep the RSS distance to the oncoming traffic it sees is vetoed or "
                   "aborted (as --decider shielded:NAME)")


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
