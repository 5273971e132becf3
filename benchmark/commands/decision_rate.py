"""``overtakezoo decision-rate``: a learned member's deployed decision rate (or OVERTAKE threshold),
chosen on its training splits and written into its run cards (benchmark/run/decision_rate.py)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from overtakezoo.benchmark.commands._options import add_parser


def register(subparsers: Any) -> None:
    p = add_parser(
        subparsers,
        "decision-rate",
        "choose a learned member's deployed decision rate (or OVERTAKE offset) on its training splits",
        "Play every run (training seed) of the member on every scenario of every training split of\n"
        "--train-suite at each candidate (multi-AV splits with every AV driven by the run), score it as the\n"
        "leaderboard does (success - 2 x crash per road, mean over splits) and write the best mean over the\n"
        "runs, with the whole table, into every run's MEMBER.json: decide_every (ties: the slower rate) or,\n"
        "with --overtake-offsets, overtake_offset (ties: the offset nearest 0). No test suite is read.\n"
        "Then `overtakezoo seeds MEMBER RUN_DIR... --ship` evaluates the seeds as deployed.",
        [
            "overtakezoo decision-rate dqn runs/dqn-s0 runs/dqn-s1 runs/dqn-s2 --jobs 2",
            "overtakezoo decision-rate ppo runs/ppo-s0 runs/ppo-s1 runs/ppo-s2 --overtake-offsets=-1.5,-1,-0.5,0",
        ],
    )
    p.add_argument("member", help="the learned member (each run directory holds MEMBER.json + MEMBER.npz)")
    p.add_argument("runs", nargs="+", type=Path, metavar="RUN_DIR", help="the member's runs (one per training seed)")
    p.add_argument("--candidates", default="10,5,2,1", help="core steps between decisions to try (default 10,5,2,1)")
    p.add_argument(
        "--overtake-offsets",
        metavar="LIST",
        help="choose the OVERTAKE score offset among these instead (at the cards' decision rate)",
    )
    p.add_argument("--train-suite", default="core-train", help="what the member trained on (its splits choose)")
    p.add_argument("--jobs", type=int, default=1, help="worker processes (one run at one candidate each; same table)")
    p.set_defaults(handler=run)


def run(args: Any) -> int:
    from overtakezoo.benchmark.errors import UserError
    from overtakezoo.benchmark.run.decision_rate import choose, parse_candidates

    knob = "overtake_offset" if args.overtake_offsets else "decide_every"
    option = "--overtake-offsets" if args.overtake_offsets else "--candidates"
    text = args.overtake_offsets or args.candidates
    try:
        candidates = parse_candidates(knob, text.split(","))
    except ValueError:
        kind = "numbers" if args.overtake_offsets else "integers"
        raise UserError(f"{option} {text!r}: expected {kind}, comma-separated") from None
    if not 1 <= args.jobs <= 64:
        raise UserError(f"--jobs {args.jobs}: expected 1..64")
    missing = [f"{r}/{args.member}.json" for r in args.runs if not (r / f"{args.member}.json").is_file()]
    if missing:
        raise UserError(f"no model card {missing[0]}")
    choose(args.member, args.runs, knob, candidates, args.train_suite, args.jobs)
    return 0
