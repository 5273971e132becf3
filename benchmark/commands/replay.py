"""``overtakezoo replay``: list or render the episodes of an MCAP archive written by ``eval --archive``."""

from __future__ import annotations

import sys
from typing import Any

from overtakezoo.benchmark.commands._options import add_parser


def register(subparsers: Any) -> None:
    p = add_parser(
        subparsers,
        "replay",
        "list or render episodes of an MCAP archive",
        "Render one archived episode (the render-mode top view) from the archive alone, or list the\n"
        "episodes with their outcomes. Episode numbers are the suite's scenario indices. A cut archive\n"
        "(an interrupted or killed run) gives its whole episodes and says what was lost.",
        [
            "overtakezoo replay run.mcap --list",
            "overtakezoo replay run.mcap --episode 17 --out ep17.gif",
            "overtakezoo replay run.mcap --episode 17 --out ep17.png   # final frame",
            "overtakezoo replay run.mcap --episode 17 --out ep17.mp4   # needs ffmpeg",
            "overtakezoo replay run.mcap --episode 17 --out ep17.json  # for the browser viewer (docs/viewer/)",
            "overtakezoo replay run.mcap --foxglove                    # how to open it in Foxglove",
        ],
    )
    p.add_argument("archive", nargs="?", help="an .mcap file written by `overtakezoo eval --archive`")
    p.add_argument("--list", action="store_true", help="list episodes: index, steps, outcome, return")
    p.add_argument("--episode", type=int, help="the episode (scenario index) to render")
    p.add_argument(
        "--out",
        help="output .gif, .mp4 or .png (default: episode-K.gif), or .json: the episode for the browser viewer "
        "(docs/viewer/index.html?episode=ep17.json)",
    )
    p.add_argument("--fps", type=float, default=10.0, help="frames per second of the animation (default 10)")
    p.add_argument("--every", type=int, default=1, help="draw every k-th step (default 1: all)")
    p.add_argument(
        "--foxglove",
        action="store_true",
        help="print how to open the archive in Foxglove with the layout shipped with OvertakeZoo",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(handler=run)


def run(args: Any) -> int:
    from overtakezoo.benchmark.archive.reader import read_index
    from overtakezoo.benchmark.archive.replay import FOXGLOVE_LAYOUT, replay
    from overtakezoo.benchmark.errors import UserError

    if args.foxglove:
        print(_foxglove_help(args.archive or "run.mcap", FOXGLOVE_LAYOUT))
        return 0
    if args.archive is None:
        raise UserError("give the archive: overtakezoo replay RUN.mcap --list (or --episode K, --foxglove)")
    if args.list:
        index = read_index(args.archive)
        print(f"{'episode':>8} {'steps':>6} {'time_s':>7} {'outcome':<8} {'return':>9}")
        for e in index.entries:
            print(
                f"{e.index:>8} {e.steps:>6} {(e.end_ns - e.start_ns) / 1e9:>7.1f} {e.outcome:<8} "
                f"{e.episode_return:>9.3f}"
            )
        print(f"{len(index.entries)} episodes")
        if index.note:
            print(f"warning: {index.note}", file=sys.stderr)
        return 0
    if args.episode is None:
        raise UserError("give --episode K to render, or --list to list the episodes")
    if args.every < 1 or args.fps <= 0:
        raise UserError("--every must be >= 1 and --fps > 0")
    note = read_index(args.archive).note
    if note:
        print(f"warning: {note}", file=sys.stderr)
    out = replay(
        args.archive,
        args.episode,
        args.out or f"episode-{args.episode}.gif",
        fps=args.fps,
        every=args.every,
        progress=not args.no_progress,
    )
    print(f"wrote {out}")
    return 0


def _foxglove_help(archive: str, layout: Any) -> str:
    return "\n".join(
        [
            f"Foxglove layout shipped with OvertakeZoo: {layout}",
            "To view an archive in Foxglove (the desktop app, or https://app.foxglove.dev in a browser):",
            f"  1. open the archive: File > Open local file... and choose {archive} (or drop it on the window);",
            "  2. load the layout: the layout menu in the top bar > Import from file... and choose the file above;",
            '  3. press play: the 3D panel follows the ego (frame "ego"), the plots show /state.mode and',
            "     /state.reward, the raw-messages panel the current /episode/summary.",
            "Episodes lie back to back on the timeline, 1 s apart; each episode's time range is in /episode/index",
            f"and in `overtakezoo replay {archive} --list` (its steps and duration). Grey translucent vehicles",
            "are those the ego's sensor does not see; the last update of an episode shows its outcome.",
        ]
    )
