"""``overtakezoo train``: train a learned member (dqn, double-dqn, ps-dqn, ppo) on a training suite,
or an offline one (bc, cql) from a recorded dataset (:mod:`..training` does the work)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from overtakezoo import zoo

from overtakezoo.benchmark.errors import UserError
from overtakezoo.envs.io import check_writable_dir

EPILOG = """examples:
  overtakezoo train dqn --suite table1-train --out runs/dqn
  overtakezoo train double-dqn --suite table1-train --steps 200000 --seed 3 --out runs/ddqn
  overtakezoo train dqn --suite table1-train --out runs/dqn --resume runs/dqn/checkpoint.pt
  overtakezoo train bc --dataset overtakezoo/table1/rule-fsm-v0 --out runs/bc
  overtakezoo train cql --dataset overtakezoo/table1/rule-fsm-v0 --seed 1 --out runs/cql

  overtakezoo train dqn --out runs/dqn --set lr=1e-3 --set hidden=[64,64]
  overtakezoo train ppo --out runs/ppo --set train.select_every=10

Writes into --out: the training log (dqn: log.csv; ppo: train_log.csv) and checkpoints (resumable),
the torch weights <algo>.pt, their numpy export <algo>.npz (what the zoo and `eval --policy` load,
no torch needed), the model card <algo>.json with the --eval-suite results (schema:
zoo/train/card.schema.json) and the runner's results file <algo>-<suite>.results.json.
`python scripts/seed_results.py ALGO RUN... --ship` publishes them into zoo/pretrained/. bc / cql
(offline, from a dataset of `overtakezoo dataset`) write no torch file, log or checkpoint.
Hyperparameter files and --set values are checked: an unknown key or an out-of-range value is one
error naming the key."""


def register(subparsers: Any) -> None:
    p = subparsers.add_parser("train", help="train a learned member (dqn, ppo, bc, ...) and evaluate it on table1",
                              description=__doc__, epilog=EPILOG,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("algorithm", choices=zoo.names("learned"), help="what to train (the zoo's learned members)")
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
    from overtakezoo.zoo.train.contract import parse_overrides

    from overtakezoo.benchmark.run.training import train

    # Bad hyperparameters, checkpoints or datasets are ConfigErrors: the CLI prints them in one line.
    trained = train(args.algorithm, suite=args.suite, dataset=args.dataset, steps=args.steps, seed=args.seed,
                    out=out, resume=args.resume, hyperparams=args.hyperparams,
                    overrides=parse_overrides(args.overrides),
                    eval_suite=None if args.eval_suite.lower() == "none" else args.eval_suite,
                    progress=not args.no_progress)
    _report(trained.card, out)
    return 0


def _report(card: dict[str, Any], out: Path) -> None:
    print(f"trained {card['name']}: {card['steps']} {card['steps_unit']} in {card['wall_time_s']:.0f} s; "
          f"files in {out}")
    res = (card.get("results") or {}).get("table1")
    if res:
        print(f"table1: success {100 * res['success_rate']:.1f} % "
              f"[{100 * res['success_ci'][0]:.1f}, {100 * res['success_ci'][1]:.1f}], "
              f"crash {100 * res['crash_rate']:.1f} % (lead lane {res['crash_lead_lane']}, "
              f"opposite lane {res['crash_opposite_lane']}), timeout {100 * res['timeout_rate']:.1f} %")
