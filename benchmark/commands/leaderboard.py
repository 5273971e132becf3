"""``overtakezoo leaderboard``: regenerate leaderboards/ from the submissions (or check it is current)."""

from __future__ import annotations

import fnmatch
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
        "leaderboard",
        "regenerate (or --check) the leaderboard files",
        "Regenerate leaderboards/ from leaderboards/submissions/: a Markdown table per suite, an\n"
        "index (index.json, README.md) and a PNG plot of success vs crash rate per suite. The output\n"
        "is byte-identical on every run. With --check nothing is written and the exit status is 1\n"
        "when any generated file is missing, different or obsolete (CI runs this); a cross-play matrix\n"
        "or failure board that misses a zoo member is named in a warning.\n"
        "With --verify nothing is written: every current row's labels are derived again (from its\n"
        "built-in zoo member, or from its stored artifact, checked by sha256) and its policy is re-run\n"
        "(artifacts in a sandboxed child process) on its scenarios: all of them for rows new or changed\n"
        "against the git base (--base; a row file git does not track yet is new; with no base, every\n"
        "row), K of each other row with --sample K, drawn from --seed (default: fresh randomness,\n"
        "printed). Every per-scenario value must equal the recorded one, and so must the row's\n"
        "recorded fresh draw (its suite's distribution with a seed nobody knew at submission);\n"
        "a row verified in full also runs a draw of verify's own (from --seed), which must agree\n"
        "with the recorded one. The first row that does not reproduce is named with its first\n"
        "mismatching scenario (exit 2). Stale rows show no numbers and are not re-run; a new or\n"
        "changed stale row is refused. The cross-play matrices (crossplay/<suite>.json) are re-run\n"
        "too: every pair of a new or changed one, max(K, 12) pairs of the others (and of every one\n"
        "with no base), all pairs without --sample; each pair's counts must equal the stored ones.\n"
        "So are the training seeds (seeds/<member>.json): each seed re-runs with its own stored\n"
        "weights (the shipped seed: the zoo member) on its suites, with the same rule for which\n"
        "(seed, suite) pairs; a seed with no weights to re-run is refused.\n"
        "--device cuda re-runs the rows, cross-play matrices and training seeds on a GPU (float64: the\n"
        "same per-scenario results as the CPU).\n"
        "Every mode\n"
        "finds its leaderboard as `submit` does (--root).",
        [
            "overtakezoo leaderboard",
            "overtakezoo leaderboard --check",
            "overtakezoo leaderboard --verify --sample 1     # CI: changed rows in full, 1 scenario of the rest",
            "overtakezoo leaderboard --verify --sample 20 --seed 1 --base HEAD  # 20 of every committed row",
            "overtakezoo leaderboard --verify --only 'table1/my-*'    # every scenario of some rows",
            "overtakezoo leaderboard --verify --device cuda           # the re-runs on a GPU",
            "overtakezoo leaderboard --root /tmp/lb",
        ],
    )
    p.add_argument("--check", action="store_true", help="write nothing; exit 1 if the files are stale")
    p.add_argument(
        "--verify",
        action="store_true",
        help="write nothing; re-run every row's policy and require its per-scenario results to match exactly",
    )
    p.add_argument(
        "--sample",
        type=int,
        metavar="K",
        help="with --verify: K scenarios of each row and max(K, 12) pairs "
        "of each cross-play matrix unchanged against --base (default: all); new or changed ones are "
        "always verified in full",
    )
    p.add_argument(
        "--seed",
        type=int,
        help="with --verify: the seed of the sample and of verify's own fresh "
        "draws (default: fresh randomness, printed, so nobody can compute them before pushing; pass it "
        "back to replay a failure)",
    )
    p.add_argument(
        "--base",
        metavar="REV",
        help="with --verify: the git revision rows are new or changed against "
        "(default: $OVERTAKEZOO_VERIFY_BASE, else the merge base of HEAD with origin/$GITHUB_BASE_REF, "
        "fetched if missing, or origin/HEAD; none outside git or when that merge base is HEAD itself, "
        "a fresh clone of the branch under test as CI runs: then every row is verified in full)",
    )
    p.add_argument("--jobs", type=int, default=1, help="with --verify: suites verified in parallel processes")
    p.add_argument(
        "--only",
        metavar="SUITE/NAME",
        help="with --verify: only rows (and cross-play "
        "matrices, as crossplay/SUITE) matching this glob, e.g. 'table1/*', '*/my-policy' or 'crossplay/duel'",
    )
    p.add_argument("--root", metavar="PATH", default=None, help=root_help())
    add_device_options(p, "the simulation of --verify's re-runs")
    p.set_defaults(handler=run)


def run(args: Any) -> int:
    from overtakezoo.benchmark.errors import UserError
    from overtakezoo.benchmark.leaderboard.coverage import uncovered
    from overtakezoo.benchmark.leaderboard.generate import stale_files, write
    from overtakezoo.benchmark.leaderboard.untrusted import check_tree

    default_core = args.device.strip().lower() == "cpu" and args.backend in (None, "numpy")
    if not args.verify and (
        any(v is not None for v in (args.sample, args.only, args.seed, args.base)) or not default_core
    ):
        raise UserError("--sample, --seed, --base, --only, --device and --backend go with --verify")
    on = device_from_args(args) if args.verify else {}  # (a missing GPU is refused before anything runs)
    args.root = leaderboard_root(args.root)
    check_tree(args.root)  # every mode reads the root: no symlink or FIFO a PR planted is followed
    if args.verify:
        from overtakezoo.benchmark.leaderboard.changes import changed_files, changed_rows, default_base
        from overtakezoo.benchmark.leaderboard.crossplay import VERIFY_PAIRS
        from overtakezoo.benchmark.leaderboard.seed_verify import SAMPLE_PAIRS, seed_files
        from overtakezoo.benchmark.leaderboard.verify import matrices, verify

        if args.sample is not None and args.sample < 1:
            raise UserError(f"--sample {args.sample}: must be >= 1")
        if args.jobs < 1:
            raise UserError(f"--jobs {args.jobs}: must be >= 1")
        base = args.base or default_base(args.root)
        changed = (
            changed_rows(args.root, base)
            | {f"{folder}/{rel}" for folder in ("crossplay", "seeds") for rel in changed_files(args.root, base, folder)}
            if base
            else set()
        )
        pairs = None if args.sample is None else max(args.sample, VERIFY_PAIRS)
        if not base and args.sample is not None:
            print(
                "no git base to compare with (outside git, or a fresh clone of the branch under test, as CI "
                f"runs): every row counts as changed and is verified in full; cross-play matrices: {pairs} "
                f"pairs each, seeds files: {SAMPLE_PAIRS} (seed, suite) pairs each, drawn from the seed (all of "
                "them without --sample)"
            )
            args.sample = None
        if base:
            shown = (
                changed
                if args.only is None
                else {  # the rows --only selects (suite/name, as load_submissions)
                    rel
                    for rel in changed
                    if fnmatch.fnmatchcase(rel.removeprefix("submissions/").removesuffix(".json"), args.only)
                }
            )
            print(
                f"rows new or changed against {base[:12]} (untracked rows are new): {len(shown)} row(s), "
                "verified in full"
            )
        n = verify(
            args.root,
            sample=args.sample,
            seed=args.seed,
            only=args.only,
            jobs=args.jobs,
            changed=changed,
            pair_sample=pairs,
            **on,
        )
        if (
            n == 0
            and args.only is not None
            and not matrices(args.root, args.only)
            and not seed_files(args.root, args.only)
        ):
            raise UserError(f"--only {args.only!r}: no current row matches")
        print(f"verified {n} row(s): every re-run reproduces its recorded per-scenario results")
        return 0
    # Measured files that miss a zoo member (or list a removed one): a warning, since a scratch board
    # may measure a few deciders (`crossplay --deciders`); the shipped board must cover the zoo
    # (tests/zoo/test_adding_a_member.py).
    short = uncovered(args.root)
    if args.check:
        stale = stale_files(args.root)
        for rel in stale:
            print(f"stale: {args.root}/{rel}", file=sys.stderr)
        for line in short:
            print(f"warning: {args.root}/{line}", file=sys.stderr)
        if stale:
            print("leaderboard is out of date: run `overtakezoo leaderboard`", file=sys.stderr)
            return 1
        print("leaderboard is up to date")
        return 0
    changed = write(args.root)
    print(
        f"leaderboard regenerated in {args.root}: {len(changed)} file(s) changed"
        + (f" ({', '.join(changed)})" if changed else "")
    )
    for line in short:
        print(f"warning: {args.root}/{line}", file=sys.stderr)
    return 0
