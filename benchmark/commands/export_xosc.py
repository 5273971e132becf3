"""``overtakezoo export-xosc``: a suite's scenarios (or a failure file's) as OpenSCENARIO + OpenDRIVE files."""

from __future__ import annotations

from typing import Any

from overtakezoo.benchmark.commands._options import add_parser


def register(subparsers: Any) -> None:
    p = add_parser(
        subparsers,
        "export-xosc",
        "write scenarios as OpenSCENARIO 1.2 (.xosc) and OpenDRIVE 1.7 (.xodr)",
        "Write one OpenSCENARIO 1.2 file and its OpenDRIVE 1.7 road per scenario (scenariogeneration,\n"
        "the [xosc] extra): start positions and speeds of the ego and the NPCs, the scripted speed changes,\n"
        "the goal and the time limit as the stop trigger, the suite's hash and the scenario's index in the\n"
        "file header. What OpenSCENARIO cannot express (reactive NPCs, the planner) is listed in\n"
        "docs/failures.md.",
        [
            "overtakezoo export-xosc --suite table1 --index 0 --index 17 --out xosc/",
            "overtakezoo export-xosc --failures failures.toml --out xosc-failures/",
            "overtakezoo export-xosc --suite oncoming-4 --out xosc-all/   # every scenario",
        ],
    )
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--suite", help="a suite name or .toml path")
    g.add_argument(
        "--failures", metavar="FILE.toml", help="a failure suite written by `overtakezoo search` (every scenario in it)"
    )
    p.add_argument(
        "--index",
        type=int,
        action="append",
        metavar="I",
        help="the scenario to export (0-based, repeatable; default: every scenario)",
    )
    p.add_argument("--out", required=True, metavar="DIR", help="folder for the files (created)")
    p.set_defaults(handler=run)


def run(args: Any) -> int:
    from overtakezoo.benchmark.errors import UserError
    from overtakezoo.benchmark.failures.xosc import export
    from overtakezoo.envs.explicit import ExplicitDistribution
    from overtakezoo.envs.suites import load_suite

    suite = load_suite(args.suite or args.failures)
    if args.failures and not isinstance(suite.distribution, ExplicitDistribution):
        raise UserError(
            f"--failures {args.failures}: lists no scenarios (not a file of `overtakezoo search`); "
            "use --suite for a drawn suite"
        )
    if args.index is not None and len(set(args.index)) != len(args.index):
        raise UserError("--index: an index is given twice")
    written = export(suite, args.out, args.index)
    print(
        f"wrote {len(written)} scenario(s) of {suite.name} (sha256 {suite.hash[:12]}) to {args.out}: "
        f"{written[0].name}" + (f" ... {written[-1].name}" if len(written) > 1 else "") + " and their .xodr roads"
    )
    return 0
