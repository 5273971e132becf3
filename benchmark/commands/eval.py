"""``overtakezoo eval``: run a decider on a suite, print Table I and write the results file."""

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
        "eval",
        "evaluate a decider on a suite",
        "Run a decider on every scenario of a suite (one batch, in chunks), print a Table I-style\n"
        "summary with 95 % CIs and write a results file (JSON). On stderr it says the hold (core steps\n"
        "per decision) and where it came from: a model card, a policy card, ONNX metadata or the\n"
        "default; a policy file without a card is warned about.",
        [
            "overtakezoo eval --suite table1 --decider always-follow",
            "overtakezoo eval --suite table1 --decider dqn --ray --shards 8   # local Ray instance",
            "overtakezoo eval --suite table1 --decider rule-fsm --out results/rule.json",
            "overtakezoo eval --suite my-suite.toml --decider dqn --shard 0/4   # first of 4 slices",
            "overtakezoo eval --suite table1 --decider rule-fsm --archive run.mcap  # + MCAP archive",
            "overtakezoo eval --suite table1 --policy runs/dqn/dqn.pt      # weights from `overtakezoo train`",
            "overtakezoo eval --suite table1 --policy model.zip            # Stable-Baselines3 ([sb3] extra)",
            "overtakezoo eval --suite table1 --policy mypkg.policies:make  # factory(config) -> decider",
            "overtakezoo eval --suite table1 --decider shielded:dqn         # dqn behind the RSS shield",
            "overtakezoo eval --suite table1 --decider dqn --device cuda     # the core on a GPU",
            "overtakezoo eval --suite table1 --decider dqn --device cuda --draw 1000000 --chunk-size 262144",
            "overtakezoo submit results/table1/dqn.shard-*-of-4.json            # merge shards",
        ],
    )
    p.add_argument("--suite", required=True, help="a suite name (see `overtakezoo suites`) or a .toml path")
    add_decider_options(p)
    p.add_argument("--out", help="results file (default: results/<suite>/<decider>[.shard-i-of-k].json)")
    p.add_argument("--shard", metavar="I/K", help="run only the I-th (0-based) of K contiguous slices")
    p.add_argument("--chunk-size", type=int, default=4096, help="scenarios stepped at once (bounds memory)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument(
        "--archive",
        metavar="RUN.mcap",
        help="also record every episode to an MCAP archive (Foxglove-ready; see `overtakezoo replay`)",
    )
    p.add_argument(
        "--scene-every",
        type=int,
        default=1,
        metavar="K",
        help="with --archive: the Foxglove scene every K-th step and at each episode's end "
        "(default 1: every step; 0: no scene)",
    )
    p.add_argument(
        "--no-safety",
        action="store_true",
        help="do not record the safety metrics (RSS, head-on "
        "TTC, abort timing: docs/metrics.md); the results file then has only Table I's arrays",
    )
    p.add_argument(
        "--ray",
        nargs="?",
        const="local",
        metavar="ADDRESS",
        help="fan shards over Ray (a local instance, or ADDRESS such as ray://head:10001 or auto) "
        "and merge them into one results file; needs the [ray] extra",
    )
    p.add_argument("--shards", type=int, default=4, help="with --ray: number of shards (default 4)")
    p.add_argument(
        "--draw",
        type=int,
        metavar="N",
        help="run N fresh scenarios of the suite's distribution and settings instead of its own (e.g. a "
        "million, on a GPU with a large --chunk-size): a measurement, not a row of the board",
    )
    p.add_argument(
        "--draw-seed", type=int, metavar="S", help="with --draw: the draw's seed (default: fresh randomness, printed)"
    )
    add_device_options(p, "the suite's simulation")
    p.set_defaults(handler=run)


def run(args: Any) -> int:
    from overtakezoo.benchmark.errors import UserError
    from overtakezoo.benchmark.run.runner import run_suite
    from overtakezoo.envs.suites import load_suite, parse_shard, shard_bounds

    suite = load_suite(args.suite)
    if args.draw is not None or args.draw_seed is not None:
        suite = _fresh_draw(suite, args.draw, args.draw_seed)
    shard = parse_shard(args.shard)
    shard_bounds(suite.count, shard)  # validates the shard against the suite
    if args.chunk_size < 1:
        raise UserError(f"--chunk-size {args.chunk_size}: must be >= 1")
    on = device_from_args(args)  # (a missing GPU is refused before anything runs)
    decider = decider_from_args(args, suite.config)
    suffix = f".shard-{shard[0]}-of-{shard[1]}" if shard else ""
    out = Path(args.out or f"results/{suite.name}/{decider.name}{suffix}.json")
    check_writable(out)
    if args.ray is not None:
        if shard or args.archive or args.no_safety or args.draw is not None:
            raise UserError(
                "--ray runs every shard itself: it cannot be combined with --shard, --archive, --no-safety or --draw"
            )
        from overtakezoo.benchmark.run.distributed import parse_address, run_suite_ray

        # Each worker loads the decider itself: by registry name, or the policy spec (a file by absolute path).
        spec = args.decider or (str(Path(args.policy).resolve()) if Path(args.policy).is_file() else args.policy)
        if args.shield:
            if args.decider is None:
                raise UserError("--ray with --shield takes --decider NAME (the workers load shielded:NAME)")
            spec = f"shielded:{args.decider}"
        results = run_suite_ray(suite, spec, args.shards, parse_address(args.ray), core=on)
        return _report(results, suite, decider, out)
    if not args.archive:
        results = run_suite(
            suite,
            decider,
            shard=shard,
            chunk_size=args.chunk_size,
            progress=not args.no_progress,
            safety=not args.no_safety,
            **on,
        )
        return _report(results, suite, decider, out)
    # the MCAP archive of every episode (benchmark/archive/recorder.py)
    from overtakezoo.benchmark.archive.recorder import recorder_for_run

    if args.scene_every < 0:
        raise UserError(f"--scene-every {args.scene_every}: must be >= 0")
    if suite.num_avs > 1:  # refused before the archive file is created
        raise UserError(
            f"suite {suite.name!r} has {suite.num_avs} automated vehicles per scenario: archives "
            "record single-ego suites only"
        )
    recorder = recorder_for_run(
        check_writable(args.archive), suite, decider, scene_every=args.scene_every, progress=not args.no_progress
    )
    try:
        with recorder:  # on Ctrl-C / SIGTERM the archive is finished with its whole episodes
            results = run_suite(
                suite,
                decider,
                shard=shard,
                chunk_size=args.chunk_size,
                progress=not args.no_progress,
                recorder=recorder,
                safety=not args.no_safety,
                **on,
            )
    except KeyboardInterrupt:
        print(f"interrupted: {args.archive} holds the {recorder.episodes} whole episodes", file=sys.stderr)
        raise
    return _report(results, suite, decider, out)


def _fresh_draw(suite: Any, count: int | None, seed: int | None) -> Any:
    """``suite``'s distribution and settings with ``count`` scenarios and ``seed`` (fresh when None)."""
    from overtakezoo.benchmark.errors import UserError
    from overtakezoo.benchmark.leaderboard.changes import fresh_seed
    from overtakezoo.benchmark.leaderboard.fresh import fresh_suite

    if count is None:
        raise UserError("--draw-seed: only with --draw N")
    if not 1 <= count <= 100_000_000:
        raise UserError(f"--draw {count}: expected 1..100000000 scenarios")
    if seed is not None and not 0 <= seed < 2**63:
        raise UserError(f"--draw-seed {seed}: expected an integer in [0, 2^63)")
    from overtakezoo.envs.explicit import ExplicitDistribution

    if isinstance(suite.distribution, ExplicitDistribution):
        raise UserError(f"--draw: suite {suite.name!r} lists its scenarios; it has no distribution to draw from")
    seed = fresh_seed() if seed is None else seed
    print(f"a fresh draw of {suite.name}: {count} scenarios, seed {seed} (not a row of the board)", file=sys.stderr)
    return fresh_suite(suite, seed, count)


def _report(results: Any, suite: Any, decider: Any, out: Path) -> int:
    from overtakezoo.benchmark.results.metrics import render_table
    from overtakezoo.benchmark.run.policy import hold_lines

    results.save(out)
    # On stderr (stdout is the results, parsed), after the run (a failure stays one error line): the
    # hold each decision got and where it came from, and a warning for a policy file without a card.
    for line in hold_lines(decider, suite.config, suite.name):
        print(line, file=sys.stderr)
    lo, hi = results.meta["range"]
    print(
        f"suite {suite.name} v{suite.version} ({suite.hash[:12]}), scenarios {lo}-{hi - 1} of {suite.count}; "
        f"decider {decider.name} v{decider.version}"
    )
    if results.num_avs > 1:  # a multi-AV suite: per-agent Table I (pooled over AVs) and the joint outcomes
        from overtakezoo.benchmark.results.metrics import format_metric
        from overtakezoo.benchmark.results.multi_metrics import JOINT, MULTI_TABLE

        print(render_table([(f"{decider.name} (per AV)", results.summary)], table=MULTI_TABLE), end="")
        print(
            "joint (per road): "
            + "; ".join(
                f"{label} {format_metric(results.summary['joint'][k], kind, unit)}" for k, label, kind, unit in JOINT
            )
        )
    else:
        print(render_table([(decider.name, results.summary)]), end="")
    print(f"wall time {results.timing['wall_time_s']:.2f} s; wrote {out}")
    return 0
