"""``overtakezoo submit``: validate a results file and file it under leaderboards/submissions/."""

from __future__ import annotations

from typing import Any

from ..cmdutil import add_parser


def register(subparsers: Any) -> None:
    p = add_parser(subparsers, "submit", "file a results file on the leaderboard",
                   "Validate a results file (or the shards of one run, merged) against the schema and the\n"
                   "current built-in suite file, and store it as leaderboards/submissions/<suite>/<decider>.json.\n"
                   "Run `overtakezoo leaderboard` afterwards to regenerate the tables.",
                   ["overtakezoo submit results/table1/always-follow.json",
                    "overtakezoo submit results/table1/dqn.shard-0-of-2.json results/table1/dqn.shard-1-of-2.json",
                    "overtakezoo submit --root /tmp/lb results.json"])
    p.add_argument("results", nargs="+", help="a results file, or every shard of one run")
    p.add_argument("--root", default="leaderboards", help="leaderboard folder (default: leaderboards)")
    p.set_defaults(handler=run)


def run(args: Any) -> int:
    from ..leaderboard import submit
    from ..results import Results, merge

    parts = [Results.load(p) for p in args.results]
    results = parts[0] if len(parts) == 1 else merge(parts)
    path = submit(results, args.root, source=" + ".join(args.results))
    print(f"filed {path}; run `overtakezoo leaderboard` to regenerate the tables")
    return 0
