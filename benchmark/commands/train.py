"""``overtakezoo train``: train a learned member on a training suite (or, offline, from a recorded
dataset) and evaluate it (:mod:`..training` does the work). The help is derived from the registry
(the members that train), the shipped model cards (the suites the zoo trained on) and the trainer
contract (the files written; the trainers with a name of their own, ``TRAINERS``: ppo-numpy)."""

from __future__ import annotations

import argparse
import json
import textwrap
from pathlib import Path
from typing import Any

from overtakezoo import zoo
from overtakezoo.benchmark.commands._options import add_device_options, device_from_args
from overtakezoo.benchmark.errors import UserError
from overtakezoo.envs.io import check_writable_dir

DEFAULT_SUITE, DEFAULT_EVAL = "table1-train", "table1"

EXAMPLES = """examples:
  overtakezoo train dqn --suite table1-train --out runs/dqn
  overtakezoo train dqn --suite core-train --out runs/dqn       # as the zoo's dqn was trained
  overtakezoo train double-dqn --suite table1-train --steps 200000 --seed 3 --out runs/ddqn
  overtakezoo train dqn --suite table1-train --out runs/dqn --resume runs/dqn/checkpoint.pt
  overtakezoo train bc --dataset overtakezoo/table1/rule-fsm-v0 --out runs/bc
  overtakezoo train cql --dataset overtakezoo/table1/rule-fsm-v0 --seed 1 --out runs/cql
  overtakezoo train dagger --suite core-train --out runs/dagger   # the oracle distilled (DAgger)

  overtakezoo train dqn --suite core-train --seeds 0,1,2 --out runs/dqn   # runs/dqn-s0, -s1, -s2 (on Ray if installed)

  overtakezoo train dqn --out runs/dqn --set lr=1e-3 --set hidden=[64,64]
  overtakezoo train ppo --out runs/ppo --set train.select_every=10
  overtakezoo train ppo-numpy --out runs/ppo-numpy   # numpy PPO, no torch: ppo-numpy.npz, not ppo's
"""


def _learned() -> list[tuple[str, str, Any]]:
    """(member, trainer module, its shipped card or None) for every learned member of the registry."""
    from overtakezoo.zoo.members.learned import PRETRAINED

    out = []
    for name in zoo.names("learned"):
        path = PRETRAINED / f"{name}.json"
        try:
            card = json.loads(path.read_text())
        except (OSError, ValueError):
            card = None
        out.append((name, zoo.member(name).trainer, card))
    return out


def _summary(learned: list[tuple[str, str, Any]]) -> tuple[str, str]:
    """The command's one-line summary and its epilog (the files, per trainer)."""
    from overtakezoo.zoo.train.contract import TRAINERS, run_files

    trained_on: dict[str, list[str]] = {}
    for name, _, card in learned:
        suite = ((card or {}).get("train_suite") or {}).get("name")
        if suite:
            trained_on.setdefault(suite, []).append(name)
    zoo_suites = "; ".join(
        f"{', '.join(names)} on {suite}" for suite, names in sorted(trained_on.items(), key=lambda kv: -len(kv[1]))
    )
    own = "; ".join(f"{name}: {what}" for name, (_, what) in TRAINERS.items())
    summary = (
        f"train a learned member ({', '.join(name for name, *_ in learned)}) or a trainer of its own "
        f"({own}) on --suite (default "
        f"{DEFAULT_SUITE}; the zoo trained {zoo_suites}) or --dataset, then evaluate it on --eval-suite "
        f"(default {DEFAULT_EVAL})"
    )
    by_trainer: dict[str, list[str]] = {}
    for name, trainer, _ in learned:
        by_trainer.setdefault(trainer, []).append(name)
    lines = [
        f"  {', '.join(names)}: {', '.join(run_files(trainer, '<member>'))}" for trainer, names in by_trainer.items()
    ] + [f"  {name}: {', '.join(run_files(module, '<member>'))}" for name, (module, _) in TRAINERS.items()]
    epilog = (
        EXAMPLES
        + "\nWrites into --out (<member> is the name trained, e.g. dqn.npz):\n"
        + "\n".join(lines)
        + "\n  and, unless --eval-suite none, the runner's results file <member>-<eval suite>.results.json\n"
        "  (the card <member>.json then holds those results too; schema: zoo/train/card.schema.json).\n"
        "The .npz is what the zoo and `eval --policy` load (no torch needed); --resume continues from a\n"
        "checkpoint (bc, cql and ppo-numpy keep none). `overtakezoo seeds ALGO RUN... --ship` publishes\n"
        "a run into zoo/pretrained/. Hyperparameter files and --set values are checked: an unknown key or\n"
        "an out-of-range value is one error naming the key. Training needs torch (ppo-numpy does not):\n"
        "pip install -e '.[train]'."
    )
    return summary, epilog


def register(subparsers: Any) -> None:
    summary, epilog = _summary(_learned())
    description = textwrap.fill(
        summary[0].upper() + summary[1:] + ".", width=100, break_on_hyphens=False
    )  # (suite names whole)
    p = subparsers.add_parser(
        "train",
        help=summary,
        description=description,
        epilog=epilog,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    from overtakezoo.zoo.train.contract import TRAINERS

    p.add_argument(
        "algorithm",
        choices=[*zoo.names("learned"), *TRAINERS],
        help="what to train: a learned member of the zoo, or a trainer of its own (not a member, its "
        f"files named after it: {', '.join(TRAINERS)})",
    )
    p.add_argument(
        "--suite",
        default=DEFAULT_SUITE,
        help=f"training suite, suites joined by + or a mixture such as core-train (default: {DEFAULT_SUITE})",
    )
    p.add_argument(
        "--dataset",
        default=None,
        metavar="NAME",
        help="bc / cql: the dataset to learn from (a name of `overtakezoo dataset list`)",
    )
    p.add_argument(
        "--steps",
        type=int,
        default=None,
        help="total training length, also when resuming (dqn: decision transitions summed over "
        "all parallel rows; bc / cql: gradient steps; default: the hyperparameter file)",
    )
    p.add_argument("--seed", type=int, default=None, help="random seed (default: the hyperparameter file)")
    p.add_argument(
        "--seeds",
        default=None,
        metavar="S,S,...",
        help="a seed sweep: one run per seed into <out>-s<seed>, in parallel on Ray when it is "
        "installed (see --engine); the same files either way",
    )
    p.add_argument(
        "--engine",
        choices=("auto", "ray", "sequential"),
        default="auto",
        help="--seeds: ray (parallel tasks on a local Ray), sequential, or auto (ray when installed)",
    )
    p.add_argument("--out", default=None, help="output directory (default: runs/<algorithm>)")
    p.add_argument(
        "--resume", default=None, metavar="CKPT", help="continue from a checkpoint the trainer wrote (see below)"
    )
    p.add_argument(
        "--hyperparams",
        default=None,
        metavar="TOML",
        help="hyperparameter file (default: zoo/hyperparams/<algorithm>.toml)",
    )
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        dest="overrides",
        help="override a hyperparameter (a TOML value; ppo, ppo-numpy: SECTION.KEY, e.g. train.steps=1000); repeatable",
    )
    p.add_argument(
        "--eval-suite",
        default=DEFAULT_EVAL,
        help=f"suite evaluated at the end ('none' to skip; default: {DEFAULT_EVAL})",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_device_options(
        p,
        "ppo-numpy's training (rollout, advantages and update in torch; zoo/train/devppo.py) and the final evaluation",
    )
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    if args.steps is not None and args.steps <= 0:
        raise UserError("--steps must be positive")
    if args.resume and not Path(args.resume).is_file():
        raise UserError(f"--resume: no checkpoint at {args.resume}")
    on = device_from_args(args)
    device = (on["device"] or "cpu") if on["backend"] == "torch" else None  # None: the numpy path
    if device is not None and args.seeds is not None:
        raise UserError("--seeds with --device: train the seeds one by one (--seed S --out DIR)")
    out = Path(args.out or f"runs/{args.algorithm}")
    from overtakezoo.benchmark.run.training import seed_dirs, train, train_seeds
    from overtakezoo.zoo.train.contract import parse_overrides

    if args.seeds is not None:
        if args.seed is not None or args.resume:
            raise UserError("--seeds runs a sweep: give it without --seed or --resume")
        try:
            seeds = [int(s) for s in args.seeds.split(",")]
        except ValueError:
            raise UserError(f"--seeds {args.seeds}: expected integers joined by commas, e.g. 0,1,2") from None
        for where in seed_dirs(out, seeds):
            check_writable_dir(where)  # an unwritable folder fails now, not after training
        cards = train_seeds(
            args.algorithm,
            seeds,
            out,
            engine=args.engine,
            suite=args.suite,
            dataset=args.dataset,
            steps=args.steps,
            hyperparams=args.hyperparams,
            overrides=parse_overrides(args.overrides),
            eval_suite=None if args.eval_suite.lower() == "none" else args.eval_suite,
            progress=not args.no_progress,
        )
        for card, where in zip(cards, seed_dirs(out, seeds), strict=True):
            _report(card, where)
        return 0
    check_writable_dir(out)  # an unwritable --out fails now, not after training
    # Bad hyperparameters, checkpoints or datasets are ConfigErrors: the CLI prints them in one line.
    trained = train(
        args.algorithm,
        suite=args.suite,
        dataset=args.dataset,
        steps=args.steps,
        seed=args.seed,
        out=out,
        resume=args.resume,
        hyperparams=args.hyperparams,
        overrides=parse_overrides(args.overrides),
        eval_suite=None if args.eval_suite.lower() == "none" else args.eval_suite,
        progress=not args.no_progress,
        device=device,
    )
    _report(trained.card, out)
    return 0


def _report(card: dict[str, Any], out: Path) -> None:
    print(
        f"trained {card['name']}: {card['steps']} {card['steps_unit']} in {card['wall_time_s']:.0f} s; files in {out}"
    )
    res = (card.get("results") or {}).get("table1")
    if res:
        print(
            f"table1: success {100 * res['success_rate']:.1f} % "
            f"[{100 * res['success_ci'][0]:.1f}, {100 * res['success_ci'][1]:.1f}], "
            f"crash {100 * res['crash_rate']:.1f} % (lead lane {res['crash_lead_lane']}, "
            f"opposite lane {res['crash_opposite_lane']}), timeout {100 * res['timeout_rate']:.1f} %"
        )
