"""``overtakezoo decision-map``: the paper's Fig. 10 (mode over NPC1 gap x NPC2 distance) for a decider."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from overtakezoo.benchmark.commands._options import add_decider_options, add_parser, decider_from_args
from overtakezoo.envs.io import check_writable


def register(subparsers: Any) -> None:
    p = add_parser(
        subparsers,
        "decision-map",
        "draw the mode a decider picks over NPC1/NPC2 positions",
        "Draw the paper's Fig. 10 for any decider: a grid of hand-made scenarios (NPC1 gap x NPC2\n"
        "distance, fixed speeds, the suite's road), one batch, and the mode the decider picks on the\n"
        "first observation of each (shown for --ticks decision ticks; the last mode is drawn).",
        [
            "overtakezoo decision-map --decider always-overtake",
            "overtakezoo decision-map --decider dqn --out fig10-dqn.png --lead-speed 1 --oncoming-speed 3",
            "overtakezoo decision-map --decider rule-fsm --gaps 5 40 --distances 10 200 --resolution 60",
            "overtakezoo decision-map --policy runs/dqn/dqn.pt --out fig10-mine.png",
        ],
    )
    add_decider_options(p)
    p.add_argument("--suite", default="table1", help="suite whose road and simulator settings are used")
    p.add_argument(
        "--out",
        help="image path; its suffix names the format: .png, .jpg/.jpeg, .svg or .pdf "
        "(default: decision-map-<decider>.png)",
    )
    p.add_argument("--lead-speed", type=float, default=2.0, help="NPC1 speed, m/s (default 2)")
    p.add_argument("--oncoming-speed", type=float, default=2.0, help="NPC2 speed, m/s (default 2)")
    p.add_argument(
        "--gaps",
        type=float,
        nargs=2,
        default=(5.0, 40.0),
        metavar=("MIN", "MAX"),
        help="NPC1 bumper gap range, m (default 5 40)",
    )
    p.add_argument(
        "--distances",
        type=float,
        nargs=2,
        default=(10.0, 150.0),
        metavar=("MIN", "MAX"),
        help="NPC2 distance range, m (default 10 150)",
    )
    p.add_argument("--resolution", type=int, default=40, help="grid cells per axis (default 40)")
    p.add_argument(
        "--ticks",
        type=int,
        default=4,
        help="decision ticks the decider sees the first observation for; the last mode is drawn "
        "(default 4: rule-fsm needs 3 consistent ticks to commit)",
    )
    p.add_argument(
        "--warmup",
        type=int,
        default=1,
        help="FOLLOW steps before the decider looks (default 1: the planner's flags are then set)",
    )
    p.set_defaults(handler=run)


def run(args: Any) -> int:
    import numpy as np

    from overtakezoo.benchmark.errors import UserError
    from overtakezoo.benchmark.run.decision_map import decision_map, image_format, plot
    from overtakezoo.envs.io import atomic_write_bytes
    from overtakezoo.envs.suites import load_suite

    if not 0 <= args.warmup <= 100:
        raise UserError(f"--warmup {args.warmup}: expected 0..100")
    if not 1 <= args.ticks <= 1000:
        raise UserError(f"--ticks {args.ticks}: expected 1..1000")
    if not 2 <= args.resolution <= 400:
        raise UserError(f"--resolution {args.resolution}: expected 2..400")
    for flag, (lo, hi) in (("--gaps", args.gaps), ("--distances", args.distances)):
        if not (0 <= lo < hi < 1e4):
            raise UserError(f"{flag} {lo:g} {hi:g}: expected 0 <= MIN < MAX")
    for flag, v in (("--lead-speed", args.lead_speed), ("--oncoming-speed", args.oncoming_speed)):
        if not 0 <= v <= 100:
            raise UserError(f"{flag} {v:g}: expected a speed in [0, 100] m/s")
    if args.out is not None:
        try:
            fmt = image_format(Path(args.out).suffix)
        except ValueError as exc:
            raise UserError(f"--out {args.out}: {exc}") from None
    else:
        fmt = "png"
    suite = load_suite(args.suite)
    decider = decider_from_args(args, suite.config)
    out = check_writable(Path(args.out or f"decision-map-{decider.name}.png"))
    dm = decision_map(
        decider,
        suite,
        np.linspace(*args.gaps, args.resolution),
        np.linspace(*args.distances, args.resolution),
        args.lead_speed,
        args.oncoming_speed,
        args.ticks,
        args.warmup,
    )
    atomic_write_bytes(out, plot(dm, fmt))
    counts = np.bincount(dm.modes.ravel(), minlength=3)
    print(f"wrote {out}: follow {counts[0]}, overtake {counts[1]}, abort {counts[2]} of {dm.modes.size} cells")
    return 0
