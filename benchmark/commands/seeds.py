"""``overtakezoo seeds``: every training seed of a learned member, evaluated; the seed to ship
(benchmark/leaderboard/seeds.py)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from overtakezoo.benchmark.commands._options import add_parser, root_help


def register(subparsers: Any) -> None:
    p = add_parser(
        subparsers,
        "seeds",
        "evaluate every training seed of a learned member; write leaderboards/seeds/MEMBER.json, ship one",
        "Run every seed (one `overtakezoo train` output directory each) on the training splits of\n"
        "--train-suite and on the test suites (--suites); write the counts to SEEDS_ROOT/seeds/MEMBER.json,\n"
        "which the leaderboard's headline reads (mean and spread over seeds), and every seed's weights to\n"
        "SEEDS_ROOT/seeds/weights/MEMBER-seedK.npz + .json, from which `leaderboard --verify` re-runs its\n"
        "counts (a seeds file needs seeds 0..n-1, n >= 3). The seed to ship is the median\n"
        "by mean success over the training splits (ties: lower crash there, then the lower seed); the test\n"
        "suites never enter the choice. --ship publishes it into zoo/pretrained/. Multi-AV suites are run with\n"
        "every AV driven by the seed. Each run's evaluations are cached in RUN_DIR/seed-eval.json.",
        [
            "overtakezoo seeds dqn runs/dqn-s0 runs/dqn-s1 runs/dqn-s2 --ship",
            "overtakezoo seeds ps-dqn runs/ps-dqn-s0 runs/ps-dqn-s1 runs/ps-dqn-s2 --ship \\\n"
            "      --train-suite core-train+multi-train --suites table1,duel --compare rule-fsm,dqn",
            "overtakezoo seeds ps-dqn --compare-only --compare dqn   # after dqn was retrained",
            "overtakezoo seeds dqn --export-shipped runs/dqn-s0   # the shipped seed, beside retrained ones",
        ],
    )
    p.add_argument("member", help="the learned member (its run directories hold MEMBER.json + weights)")
    p.add_argument("runs", nargs="*", type=Path, metavar="RUN_DIR", help="one `overtakezoo train` output per seed")
    p.add_argument("--ship", action="store_true", help="publish the chosen seed into zoo/pretrained/")
    p.add_argument("--suites", default=None, metavar="A,B,...", help="the test suites (default: the core suites)")
    p.add_argument("--no-write", action="store_true", help="only evaluate (fill each run's cache)")
    p.add_argument(
        "--train-suite",
        default=None,
        help="what the member trained on (its splits choose the seed; default: core-train)",
    )
    p.add_argument("--compare", default="", metavar="A,B,...", help="zoo members run on the multi-AV suites beside it")
    p.add_argument(
        "--compare-only",
        action="store_true",
        help="re-run only the --compare members (after one was retrained) and update the seeds file and the "
        "shipped card; the member's seeds stay",
    )
    p.add_argument(
        "--export-shipped",
        type=Path,
        default=None,
        metavar="RUN_DIR",
        help="write the zoo's shipped weights and card into this new run directory and stop: the shipped seed "
        "then runs beside seeds retrained with `overtakezoo train --seed K` (decision-rate, seeds)",
    )
    p.add_argument("--root", default=None, help=root_help())
    p.add_argument(
        "--pretrained", default=None, metavar="DIR", help="where --ship publishes (default: zoo/pretrained/)"
    )
    p.set_defaults(handler=run)


def _names(text: str, option: str) -> list[str]:
    from overtakezoo.benchmark.errors import UserError

    names = [n.strip() for n in text.split(",")]
    if not all(names):
        raise UserError(f"{option} {text!r}: expected names, comma-separated")
    return names


def run(args: Any) -> int:
    from overtakezoo.benchmark.commands._options import leaderboard_root
    from overtakezoo.benchmark.errors import UserError
    from overtakezoo.benchmark.leaderboard import seeds

    if args.export_shipped is not None:
        seed = seeds.export_shipped(args.member, args.export_shipped, args.pretrained)
        print(f"{args.member}: the shipped seed {seed} written to {args.export_shipped}")
        return 0
    root = leaderboard_root(args.root)
    if args.compare_only:
        if not args.compare:
            raise UserError("--compare-only needs --compare NAME,...")
        seeds.compare_only(args.member, _names(args.compare, "--compare"), root, args.pretrained)
        return 0
    if not args.runs:
        raise UserError("give the member's run directories")
    missing = [str(r) for r in args.runs if not r.is_dir()]
    if missing:
        raise UserError(f"no such run directory: {missing[0]}")
    seeds.run_seeds(
        args.member,
        args.runs,
        root,
        suites=_names(args.suites, "--suites") if args.suites is not None else None,
        train_suite=args.train_suite or seeds.TRAIN_SUITE,
        compare_with=_names(args.compare, "--compare") if args.compare else None,
        ship=args.ship,
        write=not args.no_write,
        pretrained=args.pretrained,
    )
    return 0
