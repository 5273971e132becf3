"""``overtakezoo failure-board``: the zoo's failures driven by every decider, and failure maps
(leaderboards/failures/)."""

from __future__ import annotations

from typing import Any

from overtakezoo.benchmark.commands._options import add_parser


def register(subparsers: Any) -> None:
    p = add_parser(
        subparsers,
        "failure-board",
        "regenerate leaderboards/failures/: failure cross-table and maps",
        "For each zoo decider, search table1 and oncoming-4 for its failures (`overtakezoo search`, seed 0)\n"
        "and sample them at random at the same budget; write each decider's failures as a suite and let\n"
        "every decider (and the oracle) drive them: crash and success rates per pair (README.md and a\n"
        "heatmap per suite); and draw each decider's failure map on table1 (maps/). The folder is\n"
        "replaced as a whole. About 4 minutes with --jobs 2 on 2 cores.",
        [
            "overtakezoo failure-board --jobs 2",
            "overtakezoo failure-board --out /tmp/board --budget 300 --deciders rule-fsm,fuzzy",
        ],
    )
    p.add_argument("--out", default="leaderboards/failures", help="the board's folder (default leaderboards/failures)")
    p.add_argument("--budget", default="1000", help="episodes per search and per random baseline (default 1000)")
    p.add_argument(
        "--deciders",
        metavar="A,B,...",
        help="rows and columns (default: every zoo member that is not "
        "privileged or shielded; the oracle is always a column)",
    )
    p.add_argument("--jobs", type=int, default=1, help="worker processes (default 1)")
    p.set_defaults(handler=run)


def run(args: Any) -> int:
    from overtakezoo.benchmark.errors import UserError
    from overtakezoo.benchmark.failures.board import write_failure_board
    from overtakezoo.benchmark.failures.search import check_budget

    args.budget = check_budget(args.budget)
    if not 1 <= args.jobs <= 64:
        raise UserError(f"--jobs {args.jobs}: expected 1..64")
    names = None
    if args.deciders is not None:
        from overtakezoo import zoo

        names = [n.strip() for n in args.deciders.split(",") if n.strip()]
        if not names or len(set(names)) != len(names):
            raise UserError(f"--deciders {args.deciders!r}: expected distinct zoo names, comma-separated")
        unknown = sorted(set(names) - set(zoo.known_names()))
        if unknown:
            raise UserError(f"--deciders: unknown decider {unknown[0]!r} (known: {', '.join(zoo.known_names())})")
    result = write_failure_board(args.out, jobs=args.jobs, budget=args.budget, deciders=names)
    t = result["timing"]
    print(f"wrote {len(result['files'])} files to {args.out} ({t['wall_s']} s wall with --jobs {t['jobs']})")
    return 0
