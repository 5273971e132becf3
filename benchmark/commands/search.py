"""``overtakezoo search``: find scenarios a decider fails (CMA-ES over the suite's ranges) and write them as a suite."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from overtakezoo.benchmark.commands._options import (
    add_decider_options,
    add_device_options,
    add_parser,
    decider_from_args,
    device_from_args,
)
from overtakezoo.envs.io import check_writable


def register(subparsers: Any) -> None:
    p = add_parser(
        subparsers,
        "search",
        "search a suite's parameter ranges for scenarios a decider fails",
        "Search the suite's scenario parameters (its distribution's ranges: speeds, gaps, distances,\n"
        "reaction times, ...) for scenarios the decider fails, with CMA-ES (the cma package): each\n"
        "generation of every CMA-ES instance is one batch on the vectorised core. Crashes are the target;\n"
        "until one is found the RSS margin and head-on TTC of each episode guide the search. Distinct\n"
        "failures are written as an explicit suite (TOML), which `eval --suite FILE`, `crossplay` and\n"
        "`export-xosc --failures FILE` read like any suite. The same --seed gives the same file, byte for\n"
        "byte. Exit status 1 (and no file) when nothing failed. See docs/failures.md.",
        [
            "overtakezoo search --decider fuzzy --suite table1 --budget 2000 --out failures.toml",
            "overtakezoo search --decider ppo --suite oncoming-4 --budget 1000 --seed 3 --out f.toml",
            "overtakezoo search --decider dqn --suite table1 --budget 500 --param lead_speed --param "
            "oncoming_gap=20:80 --out f.toml",
            "overtakezoo search --decider fuzzy --suite table1 --budget 2000 --compare-random 3 --out f.toml",
            "overtakezoo eval --suite failures.toml --decider fuzzy   # the failures, re-run",
        ],
    )
    add_decider_options(p)
    p.add_argument("--suite", required=True, help="a suite name or a .toml path (its [scenario] ranges are the box)")
    p.add_argument("--budget", required=True, metavar="N", help="simulated episodes to spend (> 0)")
    p.add_argument("--out", required=True, metavar="FILE.toml", help="the failure suite to write")
    p.add_argument("--seed", type=int, default=0, help="seed of the search (default 0)")
    p.add_argument(
        "--param",
        action="append",
        metavar="NAME[=LO:HI]",
        help="search only these parameters (repeatable); a range replaces the suite's (within the "
        "setting's physical range); sensor_range, oncoming_count and follower_count need one",
    )
    p.add_argument(
        "--target",
        default="crash",
        choices=("crash", "rss", "ttc"),
        help="what counts as a failure: crash (or off-road; default), rss (also an RSS Definition 2 "
        "violation in the opposite lane), ttc (also a head-on TTC below --ttc)",
    )
    p.add_argument("--ttc", type=float, default=1.0, metavar="S", help="with --target ttc: the TTC limit (s)")
    p.add_argument(
        "--distinct",
        type=float,
        default=0.05,
        metavar="F",
        help="failures closer than F (a share of each range, in every parameter) count once (default 0.05)",
    )
    p.add_argument("--batch", type=int, default=128, help="episodes per generation (all CMA-ES populations)")
    p.add_argument("--name", help="the failure suite's name (default <suite>-<decider>-failures)")
    p.add_argument(
        "--compare-random",
        type=int,
        default=0,
        metavar="R",
        help="also run random sampling of the suite R times at the same budget and print the ratio of "
        "distinct failures per episode (not written to the file)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_device_options(p, "each population's episodes")
    p.set_defaults(handler=run)


def command_line(args: Any) -> str:
    """The search as a command (what the file records; --out and output options left out)."""
    who = f"--decider {args.decider}" if args.decider else f"--policy {args.policy}"
    parts = ["overtakezoo search", who, f"--suite {args.suite}", f"--budget {args.budget}", f"--seed {args.seed}"]
    if args.shield:
        parts.append("--shield")
    parts += [f"--param {p}" for p in args.param or []]
    if args.target != "crash":
        parts.append(f"--target {args.target}" + (f" --ttc {args.ttc:g}" if args.target == "ttc" else ""))
    if args.distinct != 0.05:
        parts.append(f"--distinct {args.distinct:g}")
    if args.batch != 128:
        parts.append(f"--batch {args.batch}")
    return " ".join(parts)


def run(args: Any) -> int:
    import math

    from overtakezoo.benchmark.errors import UserError
    from overtakezoo.benchmark.failures.search import (
        check_budget,
        check_distinct,
        cma_search,
        default_name,
        failure_suite,
        random_search,
    )
    from overtakezoo.envs.draws import space_for
    from overtakezoo.envs.explicit import base_distribution
    from overtakezoo.envs.io import atomic_write_bytes
    from overtakezoo.envs.suites import NAME_RE, load_suite

    args.budget = check_budget(args.budget)
    check_distinct(args.distinct)
    if not 1 <= args.batch <= 1_048_576:  # (populations of 100k episodes are what a GPU makes cheap)
        raise UserError(f"--batch {args.batch}: expected 1..1048576")
    if not (math.isfinite(args.ttc) and args.ttc > 0):
        raise UserError(f"--ttc {args.ttc}: expected a positive number of seconds")
    if not 0 <= args.seed < 2**63:
        raise UserError(f"--seed {args.seed}: expected an integer in [0, 2^63)")
    if not 0 <= args.compare_random <= 100:
        raise UserError(f"--compare-random {args.compare_random}: expected 0..100")
    if args.name is not None and not NAME_RE.match(args.name):
        raise UserError(f"--name {args.name!r}: expected lowercase letters, digits, '.', '_' or '-' (64 at most)")
    suite = load_suite(args.suite)
    space = space_for(base_distribution(suite), args.param, f"suite {suite.name!r}")
    core = device_from_args(args)
    decider = decider_from_args(args, suite.config)
    out = check_writable(Path(args.out))
    command = command_line(args)
    found = cma_search(
        suite,
        decider,
        args.budget,
        args.seed,
        target=args.target,
        batch=args.batch,
        distinct=args.distinct,
        ttc_limit=args.ttc,
        progress=not args.no_progress,
        space=space,
        core=core,
    )
    per100 = 100.0 * found.rate
    print(
        f"{suite.name} / {decider.name}: {found.distinct} distinct {args.target} failures in {found.episodes} "
        f"episodes ({per100:.2f} per 100; {found.failures} failing episodes; {found.restarts} restarts; "
        f"{found.wall_s:.1f} s)"
    )
    if args.compare_random:
        randoms = [
            random_search(
                suite,
                decider,
                args.budget,
                10_000 + k,
                target=args.target,
                distinct=args.distinct,
                ttc_limit=args.ttc,
                progress=not args.no_progress,
                space=space,
                core=core,
            )
            for k in range(args.compare_random)
        ]
        r_found, r_eps = sum(r.distinct for r in randoms), sum(r.episodes for r in randoms)
        counts = ", ".join(str(r.distinct) for r in randoms)
        if r_found:
            ratio = f"ratio {found.rate / (r_found / r_eps):.1f}x"
        else:
            ratio = f"ratio at least {found.rate / (3.0 / r_eps):.1f}x (random found none; 95 % bound 3/{r_eps})"
        print(
            f"random sampling, {args.compare_random} x {args.budget} episodes: {counts} distinct failures "
            f"({100.0 * r_found / r_eps:.2f} per 100); {ratio}"
        )
    if not found.distinct:
        print(f"no failure found in {found.episodes} episodes: nothing written", file=sys.stderr)
        return 1
    data = failure_suite(
        suite,
        decider,
        found,
        name=args.name or default_name(suite, decider),
        seed=args.seed,
        budget=args.budget,
        target=args.target,
        command=command,
    )
    atomic_write_bytes(out, data)
    import hashlib

    print(f"wrote {out}: {found.distinct} scenarios, sha256 {hashlib.sha256(data).hexdigest()[:12]}")
    return 0
