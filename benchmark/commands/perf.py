"""`overtakezoo perf`: the side-by-side performance report."""

from __future__ import annotations

from typing import Any

from ..cmdutil import add_parser


def register(subparsers: Any) -> None:
    p = add_parser(subparsers, "perf", help="measure throughput, suite wall times, memory and highway-env side by side",
                   description="Measure env-steps/s of the batched core, one PettingZoo env, table1 wall times, "
                               "peak memory, and highway-env's two-way-v0 (with the [compare] extra) on this machine.",
                   examples=["overtakezoo perf", "overtakezoo perf --sizes 1 4096 --seconds 1 --no-suites",
                             "overtakezoo perf --out docs/perf"])
    p.add_argument("--sizes", type=int, nargs="+", default=[1, 256, 4096, 16384], help="batch sizes N")
    p.add_argument("--seconds", type=float, default=3.0, help="measuring time per figure")
    p.add_argument("--no-suites", action="store_true", help="skip the table1 runs and the memory figure")
    p.add_argument("--out", default=None, help="write OUT.json and OUT.md (e.g. docs/perf)")
    p.set_defaults(handler=run)


def run(args: Any) -> int:
    from ..errors import UserError
    from ..perf import measure, write_report

    if any(n < 1 for n in args.sizes) or args.seconds <= 0:
        raise UserError("--sizes must be >= 1 and --seconds > 0")
    if args.out:  # fail before measuring, not after
        from ..io import check_writable

        check_writable(args.out + ".json")
        check_writable(args.out + ".md")
    report = measure(args.sizes, args.seconds, suites=not args.no_suites)
    if args.out:
        write_report(report, args.out)
        print(f"wrote {args.out}.json and {args.out}.md")
    return 0
