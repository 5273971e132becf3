"""`overtakezoo perf`: the side-by-side performance report."""

from __future__ import annotations

from typing import Any

from overtakezoo.benchmark.commands._options import add_device_options, add_parser, device_from_args

GPU_SIZES = [4096, 65_536, 262_144, 1_048_576, 4_194_304]


def register(subparsers: Any) -> None:
    p = add_parser(
        subparsers,
        "perf",
        help="measure throughput, suite and eval times, memory and highway-env side by side",
        description="Measure env-steps/s of the batched core, one PettingZoo env, one Gymnasium env and a "
        "make_vec batch of ours and of highway-env's two-way-v0 (with the [compare] extra), "
        "table1 wall times in the runner and as an `overtakezoo eval` process, and peak "
        "memory on this machine; each figure as median and range of --repeats runs.",
        examples=[
            "overtakezoo perf",
            "overtakezoo perf --sizes 1 4096 --seconds 0.5 --no-suites",
            "overtakezoo perf --out docs/perf",
            "overtakezoo perf --only-training --out docs/perf-training",
            "overtakezoo perf --device cuda --out docs/perf-gpu   # the GPU rows beside the numpy core",
            "overtakezoo perf --backend torch --sizes 256 4096 --seconds 0.5   # the same rows, torch on the CPU",
        ],
    )
    p.add_argument("--sizes", type=int, nargs="+", default=None, help="core batch sizes N (default 1 8 256 4096 16384)")
    p.add_argument("--batch", type=int, default=8, help="N of the make_vec batches compared with highway-env")
    p.add_argument("--seconds", type=float, default=1.0, help="measuring window per run")
    p.add_argument("--repeats", type=int, default=3, help="runs per figure (median and range reported)")
    p.add_argument("--eval-runs", type=int, default=5, help="`overtakezoo eval` processes timed")
    p.add_argument("--no-suites", action="store_true", help="skip the table1 runs, the eval processes and memory")
    p.add_argument(
        "--no-training",
        action="store_true",
        help="skip the training rows (train-throughput-core-train, "
        "time-to-paper-level: several minutes; need the [train] extra)",
    )
    p.add_argument("--only-training", action="store_true", help="only the training rows")
    p.add_argument("--out", default=None, help="write OUT.json and OUT.md (e.g. docs/perf)")
    p.add_argument(
        "--compile",
        action="store_true",
        help="with --device / --backend torch: also the step fused by torch.compile (about half a minute "
        "of compiling per N; needs a C++ compiler on the CPU, Triton on a GPU)",
    )
    add_device_options(
        p,
        "the device rows' core (given: only the device rows, --sizes defaulting to "
        "4096 65536 262144 1048576 4194304 on a GPU)",
    )
    p.set_defaults(handler=run)


def run(args: Any) -> int:
    from overtakezoo.benchmark.errors import UserError
    from overtakezoo.benchmark.run.perf import measure, write_report

    on = device_from_args(args)
    device = (on["device"] or "cpu") if on["backend"] == "torch" else None  # None: the CPU report
    if args.sizes is None:
        args.sizes = GPU_SIZES if device and device != "cpu" else [256, 4096] if device else [1, 8, 256, 4096, 16384]
    if args.compile and not device:
        raise UserError("--compile: only with --device cuda or --backend torch (the numpy core is not compiled)")
    if device and (args.only_training or args.no_suites):
        raise UserError("--device / --backend torch measures the device rows only: no --only-training or --no-suites")
    if any(n < 1 for n in args.sizes) or min(args.batch, args.repeats, args.eval_runs) < 1 or args.seconds <= 0:
        raise UserError("--sizes, --batch, --repeats and --eval-runs must be >= 1 and --seconds > 0")
    if args.no_training and args.only_training:
        raise UserError("--no-training and --only-training exclude each other")
    if args.out:  # fail before measuring, not after
        from overtakezoo.envs.io import check_writable

        check_writable(args.out + ".json")
        check_writable(args.out + ".md")
    report = measure(
        args.sizes,
        args.seconds,
        repeats=args.repeats,
        batch=args.batch,
        eval_runs=args.eval_runs,
        suites=not args.no_suites,
        training=not args.no_training,
        only_training=args.only_training,
        device=device,
        compile=args.compile,
    )
    if args.out:
        write_report(report, args.out)
        print(f"wrote {args.out}.json and {args.out}.md")
    return 0
