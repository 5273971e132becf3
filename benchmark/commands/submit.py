"""``overtakezoo submit``: file a results file, with the policy that re-runs it, under leaderboards/submissions/."""

from __future__ import annotations

import os
import shlex
import sys
from typing import Any

from overtakezoo.benchmark.commands._options import (
    add_device_options,
    add_parser,
    device_from_args,
    leaderboard_root,
    root_help,
)


def register(subparsers: Any) -> None:
    p = add_parser(
        subparsers,
        "submit",
        "file a results file on the leaderboard",
        "Validate a results file (or the shards of one run, merged) against the schema and the\n"
        "current built-in suite file, environment config and simulator version, and file it as the row\n"
        "leaderboards/submissions/<suite>/<name>.json together with the policy that re-runs it:\n"
        "a built-in zoo member (filed under its own name; its version and weights must be the zoo's\n"
        "current ones), or your policy file (--policy, stored once by sha256 in\n"
        "leaderboards/submissions/artifacts/) under a name of your own (--name; built-in names are\n"
        "reserved). An existing row is replaced only with --replace. A policy file is re-run on every\n"
        "scenario, and every row's policy on a fresh draw of the suite, on the core --device picks (the\n"
        "same per-scenario results on a GPU). Then run\n"
        "`overtakezoo leaderboard --verify --only SUITE/NAME` and `overtakezoo leaderboard`.",
        [
            "overtakezoo submit results/table1/rule-fsm.json",
            "overtakezoo submit results/table1/my-ppo.json --policy my-ppo.zip --name my-ppo",
            "overtakezoo submit results/table1/mine.json --policy runs/dqn/dqn.pt --name my-dqn  # + dqn.json",
            "overtakezoo submit results/table1/dqn.shard-0-of-2.json results/table1/dqn.shard-1-of-2.json",
            "overtakezoo submit --replace --root /tmp/lb results.json",
            "overtakezoo submit results/table1/mine.json --policy mine.onnx --name mine --device cuda  # on a GPU",
        ],
    )
    p.add_argument("results", nargs="+", help="a results file, or every shard of one run")
    p.add_argument("--name", help="the row's name (default: the decider's name; zoo names are reserved for the zoo)")
    p.add_argument(
        "--policy",
        metavar="FILE",
        help="the policy file the results were measured with (as given to "
        "`eval --policy`; weights from `overtakezoo train` are stored with their model card); "
        "needed for every decider that is not a built-in zoo member",
    )
    p.add_argument("--replace", action="store_true", help="replace an existing row of the same name")
    p.add_argument("--root", metavar="PATH", default=None, help=root_help(new_ok=True))
    add_device_options(p, "submit's simulation (the re-run of a policy file, the fresh draw)")
    p.set_defaults(handler=run)


def run(args: Any) -> int:
    from overtakezoo.benchmark.leaderboard.submission import submit
    from overtakezoo.benchmark.results.results import Results, merge

    on = device_from_args(args)  # (a missing GPU is refused before anything runs)
    root = leaderboard_root(args.root, new_ok=True)
    parts = [Results.load(p) for p in args.results]
    results = parts[0] if len(parts) == 1 else merge(parts)
    new = not os.path.lexists(root)
    path = submit(
        results,
        root,
        name=args.name,
        policy=args.policy,
        replace=args.replace,
        source=" + ".join(args.results),
        report=lambda line: print(line, file=sys.stderr),
        **on,
    )  # the hold
    if new:
        print(f"started a new leaderboard in {root}")
    at = f" --root {shlex.quote(args.root)}" if args.root is not None else ""
    print(
        f"filed {path}; check it with `overtakezoo leaderboard{at} --verify --only "
        f"'{path.parent.name}/{path.stem}'`, then run `overtakezoo leaderboard{at}` to regenerate the tables"
    )
    return 0
