"""``overtakezoo crossplay``: every zoo decider against every other on a multi-AV suite (crossplay.py)."""

from __future__ import annotations

import sys
from typing import Any

from overtakezoo.benchmark.commands._options import add_device_options, add_parser, device_from_args


def register(subparsers: Any) -> None:
    p = add_parser(
        subparsers,
        "crossplay",
        "measure the cross-play matrix of the zoo on a multi-AV suite (A drives the ego, B every other AV)",
        "Decider A drives AV 0 (the ego), decider B every other AV (one B per AV) of the suite's first K\n"
        "scenarios, for every ordered pair of zoo deciders (the privileged oracle left out). Writes the\n"
        "counts to <root>/crossplay/<suite>.json and regenerates the leaderboard, which turns them into\n"
        "crossplay-<suite>.md (joint success and AV-AV crash matrices with 95 % Wilson intervals) and\n"
        "crossplay-<suite>.png (heatmaps). With --check nothing is written: the matrix is measured again\n"
        "and the exit status is 1 when it differs from the stored one. --device cuda runs the pairs on a GPU\n"
        "(the same counts).",
        [
            "overtakezoo crossplay --suite duel --jobs 2",
            "overtakezoo crossplay --suite duel --limit 50 --deciders rule-fsm,fuzzy,dqn --root /tmp/lb",
            "overtakezoo crossplay --suite platoon --jobs 2",
            "overtakezoo crossplay --suite platoon --jobs 2 --changed-only   # after retraining a member",
            "overtakezoo crossplay --suite duel --check --jobs 2",
            "overtakezoo crossplay --suite duel --device cuda     # the pairs on a GPU",
        ],
    )
    p.add_argument("--suite", default="duel", help="a multi-AV suite: duel, platoon, mixed-traffic (default: duel)")
    p.add_argument("--limit", type=int, metavar="K", help="scenarios per pair, the suite's first K (default: 500)")
    p.add_argument("--deciders", metavar="A,B,...", help="zoo deciders to pair (default: every non-privileged member)")
    p.add_argument("--jobs", type=int, default=1, help="rows of the matrix measured in parallel processes")
    p.add_argument(
        "--check", action="store_true", help="write nothing; exit 1 if a re-run differs from the stored matrix"
    )
    p.add_argument(
        "--changed-only",
        action="store_true",
        help="re-run only the pairs with a decider whose "
        "version or weights differ from the stored matrix; copy the rest (every pair is deterministic)",
    )
    p.add_argument("--root", default="leaderboards", help="leaderboard folder (default: leaderboards)")
    add_device_options(p, "the pairs' simulation")
    p.set_defaults(handler=run)


def run(args: Any) -> int:
    from overtakezoo.benchmark.errors import UserError
    from overtakezoo.benchmark.leaderboard import crossplay
    from overtakezoo.benchmark.leaderboard.generate import write
    from overtakezoo.benchmark.leaderboard.untrusted import check_tree
    from overtakezoo.envs.io import atomic_write_bytes
    from overtakezoo.envs.suites import load_suite

    if args.jobs < 1:
        raise UserError(f"--jobs {args.jobs}: must be >= 1")
    on = device_from_args(args)  # (a missing GPU is refused before anything runs)
    suite = load_suite(args.suite)
    names = None
    if args.deciders is not None:
        names = [n.strip() for n in args.deciders.split(",") if n.strip()]
        if len(set(names)) != len(names) or not names:
            raise UserError(f"--deciders {args.deciders!r}: expected distinct zoo names, comma-separated")
        from overtakezoo import zoo

        unknown = sorted(set(names) - set(zoo.known_names()))
        if unknown:
            raise UserError(f"--deciders: unknown decider {unknown[0]!r} (known: {', '.join(zoo.known_names())})")
    path = crossplay.data_path(args.root, suite.name)
    check_tree(args.root)  # a PR's link or FIFO under the root: refused before reading or writing there
    if args.check:
        if not path.is_file():
            raise UserError(f"{path}: no stored matrix to check (run `overtakezoo crossplay --suite {suite.name}`)")
        stored = crossplay.load(path)
        if names is None:
            names = [d["name"] for d in stored["deciders"]]
        doc = crossplay.measure(
            suite, names, stored["scenarios"] if args.limit is None else args.limit, args.jobs, **on
        )
        if crossplay.to_bytes(doc) != path.read_bytes():
            print(
                f"stale: {path} differs from a re-run: run `overtakezoo crossplay --suite {suite.name}`",
                file=sys.stderr,
            )
            return 1
        print(f"{path} reproduces: {len(doc['pairs'])} pairs on {doc['scenarios']} scenarios each")
        return 0
    if args.changed_only and args.check:
        raise UserError("--changed-only and --check: a check re-runs every pair")
    stored = crossplay.load(path) if args.changed_only and path.is_file() else None
    doc = crossplay.measure(
        suite, names, crossplay.DEFAULT_SCENARIOS if args.limit is None else args.limit, args.jobs, stored, **on
    )
    atomic_write_bytes(path, crossplay.to_bytes(doc))
    changed = write(args.root)
    print(
        f"measured {len(doc['pairs'])} pairs on {doc['scenarios']} scenarios of {suite.name}; wrote {path}; "
        f"leaderboard regenerated: {len(changed)} file(s) changed" + (f" ({', '.join(changed)})" if changed else "")
    )
    return 0
