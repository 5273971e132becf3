"""``overtakezoo leaderboard``: regenerate leaderboards/ from the submissions (or check it is current)."""

from __future__ import annotations

import sys
from typing import Any

from ..cmdutil import add_parser


def register(subparsers: Any) -> None:
    p = add_parser(subparsers, "leaderboard", "regenerate (or --check) the leaderboard files",
                   "Regenerate leaderboards/ from leaderboards/submissions/: a Markdown table per suite, an\n"
                   "index (index.json, README.md) and a PNG plot of success vs crash rate per suite. The output\n"
                   "is byte-identical on every run. With --check nothing is written and the exit status is 1\n"
                   "when any generated file is missing, different or obsolete (CI runs this).",
                   ["overtakezoo leaderboard", "overtakezoo leaderboard --check",
                    "overtakezoo leaderboard --root /tmp/lb"])
    p.add_argument("--check", action="store_true", help="write nothing; exit 1 if the files are stale")
    p.add_argument("--root", default="leaderboards", help="leaderboard folder (default: leaderboards)")
    p.set_defaults(handler=run)


def run(args: Any) -> int:
    from ..leaderboard import stale_files, write

    if args.check:
        stale = stale_files(args.root)
        for rel in stale:
            print(f"stale: {args.root}/{rel}", file=sys.stderr)
        if stale:
            print("leaderboard is out of date: run `overtakezoo leaderboard`", file=sys.stderr)
            return 1
        print("leaderboard is up to date")
        return 0
    changed = write(args.root)
    print(f"leaderboard regenerated in {args.root}: {len(changed)} file(s) changed"
          + (f" ({', '.join(changed)})" if changed else ""))
    return 0
