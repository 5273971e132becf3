"""``overtakezoo replay``: list or render the episodes of an MCAP archive written by ``eval --archive``."""

from __future__ import annotations

from typing import Any

from ..cmdutil import add_parser


def register(subparsers: Any) -> None:
    p = add_parser(subparsers, "replay", "list or render episodes of an MCAP archive",
                   "Render one archived episode (the render-mode top view) from the archive alone, or list the\n"
                   "episodes with their outcomes. Episode numbers are the suite's scenario indices.",
                   ["overtakezoo replay run.mcap --list",
                    "overtakezoo replay run.mcap --episode 17 --out ep17.gif",
                    "overtakezoo replay run.mcap --episode 17 --out ep17.png   # final frame",
                    "overtakezoo replay run.mcap --episode 17 --out ep17.mp4   # needs ffmpeg"])
    p.add_argument("archive", help="an .mcap file written by `overtakezoo eval --archive`")
    p.add_argument("--list", action="store_true", help="list episodes: index, steps, outcome, return")
    p.add_argument("--episode", type=int, help="the episode (scenario index) to render")
    p.add_argument("--out", help="output .gif, .mp4 or .png (default: episode-K.gif)")
    p.add_argument("--fps", type=float, default=10.0, help="frames per second of the animation (default 10)")
    p.add_argument("--every", type=int, default=1, help="draw every k-th step (default 1: all)")
    p.set_defaults(handler=run)


def run(args: Any) -> int:
    from ..archive import list_episodes
    from ..errors import UserError
    from ..replay import replay

    if args.list:
        entries = list_episodes(args.archive)
        print(f"{'episode':>8} {'steps':>6} {'time_s':>7} {'outcome':<8} {'return':>9}")
        for e in entries:
            print(f"{e.index:>8} {e.steps:>6} {(e.end_ns - e.start_ns) / 1e9:>7.1f} {e.outcome:<8} "
                  f"{e.episode_return:>9.3f}")
        print(f"{len(entries)} episodes")
        return 0
    if args.episode is None:
        raise UserError("give --episode K to render, or --list to list the episodes")
    if args.every < 1 or args.fps <= 0:
        raise UserError("--every must be >= 1 and --fps > 0")
    out = replay(args.archive, args.episode, args.out or f"episode-{args.episode}.gif", fps=args.fps,
                 every=args.every)
    print(f"wrote {out}")
    return 0
