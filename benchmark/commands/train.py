"""``overtakezoo train``: train a learned decider (dqn, double-dqn, ppo) on a training suite, or an
offline one (bc, cql) from a recorded dataset."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from overtakezoo.benchmark.errors import UserError
from overtakezoo.envs.io import check_writable_dir

ALGORITHMS = ("dqn", "double-dqn", "ps-dqn", "ppo", "bc", "cql")
OFFLINE = ("bc", "cql")  # trained from a dataset (--dataset), not by interaction

EPILOG = """examples:
  overtakezoo train dqn --suite table1-train --out runs/dqn
  overtakezoo train double-dqn --suite table1-train --steps 200000 --seed 3 --out runs/ddqn
  overtakezoo train dqn --suite table1-train --out runs/dqn --resume runs/dqn/checkpoint.pt
  overtakezoo train bc --dataset overtakezoo/table1/rule-fsm-v0 --out runs/bc
  overtakezoo train cql --dataset overtakezoo/table1/rule-fsm-v0 --seed 1 --out runs/cql

  overtakezoo train dqn --out runs/dqn --set lr=1e-3 --set hidden=[64,64]
  overtakezoo train ppo --out runs/ppo --set train.select_every=10

Writes into --out: log.csv (steps, episodes, success / crash rate, loss, epsilon, wall time),
checkpoint.pt (resumable), the torch weights <algo>.pt, their numpy export <algo>.npz (what the
zoo and `eval --policy` load, no torch needed) and the model card <algo>.json with the table1
evaluation. `python scripts/seed_results.py ALGO RUN... --ship` publishes them into zoo/pretrained/.
bc / cql (offline, from a dataset of `overtakezoo dataset`) write <algo>.npz and <algo>.json, and
no log or checkpoint. Hyperparameter files and --set values are checked: an unknown key or an
out-of-range value is one error naming the key."""


def register(subparsers: Any) -> None:
    p = subparsers.add_parser("train", help="train dqn / double-dqn / ppo / bc / cql and evaluate on table1",
                              description=__doc__, epilog=EPILOG,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("algorithm", choices=ALGORITHMS, help="what to train")
    p.add_argument("--suite", default="table1-train", help="training suite (default: table1-train)")
    p.add_argument("--dataset", default=None, metavar="NAME",
                   help="bc / cql: the dataset to learn from (a name of `overtakezoo dataset list`)")
    p.add_argument("--steps", type=int, default=None,
                   help="total training length, also when resuming (dqn: decision transitions summed over "
                        "all parallel rows; bc / cql: gradient steps; default: the hyperparameter file)")
    p.add_argument("--seed", type=int, default=None, help="random seed (default: the hyperparameter file)")
    p.add_argument("--out", default=None, help="output directory (default: runs/<algorithm>)")
    p.add_argument("--resume", default=None, metavar="CKPT", help="continue from a checkpoint.pt")
    p.add_argument("--hyperparams", default=None, metavar="TOML",
                   help="hyperparameter file (default: zoo/hyperparams/<algorithm>.toml)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", dest="overrides",
                   help="override a hyperparameter (a TOML value; ppo: SECTION.KEY, e.g. train.steps=1000); "
                        "repeatable")
    p.add_argument("--eval-suite", default="table1", help="suite evaluated at the end ('none' to skip)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    if args.steps is not None and args.steps <= 0:
        raise UserError("--steps must be positive")
    if args.resume and not Path(args.resume).is_file():
        raise UserError(f"--resume: no checkpoint at {args.resume}")
    out = Path(args.out or f"runs/{args.algorithm}")
    check_writable_dir(out)  # an unwritable --out fails now, not after training
    eval_suite = None if args.eval_suite.lower() == "none" else args.eval_suite
    if args.algorithm in OFFLINE:
        return _run_offline(args, out, eval_suite)
    if args.dataset:
        raise UserError(f"--dataset is for bc / cql; {args.algorithm} trains on --suite")
    if args.algorithm == "ppo":
        return _run_ppo(args, out, eval_suite)
    from overtakezoo.zoo.train_dqn import TrainError, train

    try:
        card = train(args.algorithm, suite=args.suite, steps=args.steps, seed=args.seed, out=out,
                     resume=args.resume, hyperparams=args.hyperparams, eval_suite=eval_suite,
                     progress=not args.no_progress, overrides=_overrides(args))
    except TrainError as exc:  # bad hyperparameter file or checkpoint (unknown suites raise UserError)
        raise UserError(str(exc)) from None
    _report(card, out)
    return 0


def _run_offline(args: argparse.Namespace, out: Path, eval_suite: str | None) -> int:
    if not args.dataset:
        raise UserError(f"{args.algorithm} learns from a dataset: give --dataset NAME (see `overtakezoo dataset list`)")
    if args.resume:
        raise UserError(f"{args.algorithm} keeps no checkpoint (it trains in minutes): run it again without --resume")
    import importlib

    module = importlib.import_module(f"overtakezoo.zoo.train_{args.algorithm}")
    try:
        card = module.train(args.dataset, seed=args.seed, steps=args.steps, out=out, hyperparams=args.hyperparams,
                            eval_suite=eval_suite, progress=not args.no_progress)
    except ValueError as exc:  # a bad hyperparameter file or dataset (missing datasets raise UserError)
        raise UserError(f"{args.algorithm}: {exc}") from None
    _report(card, out)
    return 0


def _run_ppo(args: argparse.Namespace, out: Path, eval_suite: str | None) -> int:
    from overtakezoo.zoo import train_ppo

    kwargs: dict[str, Any] = {"suite": args.suite, "steps": args.steps, "out": out, "resume": args.resume,
                              "eval_suite": eval_suite, "progress": not args.no_progress,
                              "overrides": _overrides(args)}
    if args.seed is not None:
        kwargs["seed"] = args.seed
    if args.hyperparams:
        kwargs["hyperparams"] = args.hyperparams
    try:
        weights = train_ppo.train(**kwargs)
    except (ValueError, FileNotFoundError) as exc:  # a bad hyperparameter file or checkpoint: one line
        raise UserError(f"ppo: {exc}") from None
    _report(json.loads((weights.parent / "ppo.json").read_text()), out)
    return 0


def _overrides(args: argparse.Namespace) -> dict[str, Any]:
    from overtakezoo.zoo.schema import HyperparameterError, parse_overrides

    try:
        return parse_overrides(args.overrides)
    except HyperparameterError as exc:
        raise UserError(str(exc)) from None


def _report(card: dict[str, Any], out: Path) -> None:
    steps = card.get("steps", card.get("training", {}).get("gradient_steps", "?"))
    print(f"trained {card.get('name', '?')}: {steps} steps in {card.get('wall_time_s', 0):.0f} s; "
          f"files in {out}")
    res = (card.get("results") or {}).get("table1")
    if res:
        print(f"table1: success {100 * res['success_rate']:.1f} % "
              f"[{100 * res['success_ci'][0]:.1f}, {100 * res['success_ci'][1]:.1f}], "
              f"crash {100 * res['crash_rate']:.1f} % (lead lane {res['crash_lead_lane']}, "
              f"opposite lane {res['crash_opposite_lane']}), timeout {100 * res['timeout_rate']:.1f} %")
