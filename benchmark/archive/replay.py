"""Replay an archived episode from the MCAP file alone: frames for the render-mode top view.

Frames are the dicts :class:`overtakezoo.envs.faces.render.TopView` draws (the same view as
``render_mode``), here with an overview of the whole road above it. One figure is drawn per
frame with its artists moved, not rebuilt; a GIF goes from the Agg buffer through Pillow, an MP4
through ``ffmpeg`` (needed on PATH), a PNG is the final frame.
"""

from __future__ import annotations

import shutil
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from overtakezoo.benchmark.archive.reader import Episode, read_archive_meta, read_episode
from overtakezoo.benchmark.errors import UserError
from overtakezoo.envs import OUTCOME_NAMES, PlannerConfig, safe_json
from overtakezoo.envs.io import atomic_path

RUNNING = 0
FOXGLOVE_LAYOUT = Path(__file__).parent / "foxglove" / "overtakezoo-layout.json"  # shipped as package data


def _planner(meta: dict[str, str]) -> dict[str, float]:
    """The planner geometry the drawing needs, from the config stored in the archive."""
    defaults = PlannerConfig()
    stored = safe_json.loads(meta.get("config", "{}"), "archive metadata: config").get("planner", {}) or {}
    keys = ("roll_in_speed_factor", "roll_in_margin", "car_tip_margin", "horizon_time")
    return {k: float(stored.get(k, getattr(defaults, k))) for k in keys}


def episode_frames(ep: Episode, meta: dict[str, str], every: int = 1) -> list[dict[str, Any]]:
    """One frame per ``every``-th step (and always the last one)."""
    pc, sc = _planner(meta), ep.scenario
    last = len(ep.t) - 1
    steps = sorted(set(range(0, last + 1, max(1, every))) | {last})
    outcome = OUTCOME_NAMES.index(ep.outcome)
    crash_npc = int(ep.summary.get("crash_npc", -1))
    arr = lambda key, dtype=float: np.asarray(sc[key], dtype=dtype)  # noqa: E731
    frames = []
    for k in steps:
        v = float(ep.ego["v"][k])
        frame = {
            "t": float(ep.t[k]),
            "mode": int(ep.mode[k - 1]) if k else 0,
            "outcome": outcome if k == last else RUNNING,
            "crash_npc": crash_npc if k == last else -1,
            "ego_x": float(ep.ego["x"][k]),
            "ego_y": float(ep.ego["y"][k]),
            "ego_psi": float(ep.ego["psi"][k]),
            "ego_v": v,
            "ego_length": float(sc["ego_length"]),
            "ego_width": float(sc["ego_width"]),
            "lane_width": float(sc["lane_width"]),
            "goal_s": float(sc["goal_s"]),
            "road_length": float(sc["road_length"]),
            "sensor_range": float(sc["sensor_range"]),
            "npc_present": arr("npc_present", bool),
            "npc_lane": arr("npc_lane", np.int8),
            "npc_s": ep.npc_s[k],
            "npc_v": ep.npc_v[k],
            "npc_length": arr("npc_length"),
            "npc_width": arr("npc_width"),
            "npc_reveal": arr("npc_reveal"),
            "roll_in": pc["roll_in_speed_factor"] * v + pc["roll_in_margin"],
            "tip_margin": pc["car_tip_margin"],
            "horizon_time": pc["horizon_time"],
        }
        if k:
            frame.update(
                plan_offsets=ep.offsets[k - 1], plan_blocked=ep.blocked[k - 1], plan_rollout=int(ep.rollout[k - 1])
            )
        frames.append(frame)
    return frames


def road_extent(ep: Episode) -> tuple[float, float]:
    """The x range of the overview: the whole road from the start to the goal, with every vehicle at
    every step of the episode (the oncoming car is in view long before the sensor sees it)."""
    sc = ep.scenario
    present = np.asarray(sc["npc_present"], dtype=bool)
    xs = [ep.ego["x"], ep.npc_s[:, present].ravel(), [float(sc["goal_s"])]]
    lo, hi = min(float(np.min(x)) for x in xs if len(x)), max(float(np.max(x)) for x in xs if len(x))
    pad = 0.03 * (hi - lo) + 5.0
    return lo - pad, hi + pad


def replay(
    path: str | Path, episode: int, out: str | Path, fps: float = 10.0, every: int = 1, progress: bool = False
) -> Path:
    """Render episode ``episode`` of archive ``path`` to ``out`` (.gif, .mp4 or .png): an overview of
    the whole road above the view that follows the ego. One figure; its artists move per frame.
    A ``.json`` ``out`` is the episode for the browser viewer instead (:mod:`.web`; ``fps`` and
    ``every`` do not apply: it holds every step)."""
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix == ".json":  # the browser viewer's file (docs/viewer/), not a drawing
        from overtakezoo.benchmark.archive.web import export_episode

        return export_episode(path, episode, out)
    if suffix not in (".gif", ".mp4", ".png"):
        raise UserError(f"--out must end in .gif, .mp4, .png or .json, got {out.name!r}")
    if suffix == ".mp4" and shutil.which("ffmpeg") is None:
        raise UserError("writing .mp4 needs ffmpeg on PATH (not found); use --out ep.gif instead")
    ep = read_episode(path, episode)
    frames = episode_frames(ep, read_archive_meta(path), every=1 if suffix == ".png" else every)

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from tqdm import tqdm

    from overtakezoo.envs.faces.render import TopView

    fig = Figure(figsize=(12.0, 3.4), dpi=DPI)
    FigureCanvasAgg(fig)
    top = fig.add_axes((0.01, 0.56, 0.98, 0.3))
    follow = fig.add_axes((0.01, 0.02, 0.98, 0.46))
    views = [TopView(top, extent=road_extent(ep), title=False), TopView(follow)]
    top.tick_params(labelsize=7, pad=1)
    follow.set_xticks([])  # the follow view moves; the overview above carries the s axis
    follow.set_xlabel("")

    def draw(i: int) -> None:
        for view in views:
            view.update(frames[i])
        top.set_title(f"episode {ep.index}    s (m): whole road, start to goal", fontsize=9, loc="left")

    try:
        with atomic_path(out) as tmp:  # a temp file beside out, renamed when complete
            if suffix == ".png":
                draw(len(frames) - 1)
                fig.savefig(tmp)
                return out
            bar = tqdm(
                total=len(frames),
                unit="frame",
                desc=out.name,
                leave=False,
                disable=not progress or not sys.stderr.isatty(),
            )
            images = _blit_frames(fig, views, draw, len(frames))
            if suffix == ".gif":
                _write_gif(images, tmp, fps, bar)
            else:
                _write_mp4(images, tmp, fps, bar)
            bar.close()
    except OSError as exc:
        raise UserError(f"cannot write {out}: {exc.strerror or exc}") from None
    return out


def _blit_frames(fig: Any, views: list[Any], draw: Any, n: int) -> Iterator[memoryview]:
    """RGBA frames (the canvas buffer, valid until the next frame): the still parts of the figure drawn
    once, the moving artists drawn over a copy of it per frame (matplotlib's blitting), so a frame
    costs the vehicles and lines, not the axes."""
    draw(0)
    for view in views:
        for artist in view.moving():
            artist.set_animated(True)
    canvas = fig.canvas
    canvas.draw()
    background = canvas.copy_from_bbox(fig.bbox)
    for i in range(n):
        draw(i)
        canvas.restore_region(background)
        for view in views:
            for artist in view.moving():
                view.ax.draw_artist(artist)
        yield canvas.buffer_rgba()


def _write_gif(images: Iterator[memoryview], out: Path, fps: float, bar: Any) -> None:
    """Frames into Pillow, each on its own palette (fast octree: the drawing uses few colours), one save."""
    from PIL import Image

    frames = []
    for rgb in images:
        rgba = Image.fromarray(np.asarray(rgb))  # a view of the canvas: quantize copies it
        frames.append(rgba.quantize(colors=64, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE))
        bar.update()
    frames[0].save(out, save_all=True, append_images=frames[1:], duration=int(round(1000 / fps)), loop=0)


def _write_mp4(images: Iterator[memoryview], out: Path, fps: float, bar: Any) -> None:
    """Raw RGB frames piped to ffmpeg (H.264, yuv420p: plays everywhere)."""
    import subprocess

    proc = None
    for rgba in images:
        rgb = np.asarray(rgba)[..., :3]
        if proc is None:
            h, w = rgb.shape[:2]
            proc = subprocess.Popen(
                [
                    "ffmpeg",
                    "-loglevel",
                    "error",
                    "-y",
                    "-f",
                    "rawvideo",
                    "-pix_fmt",
                    "rgb24",
                    "-s",
                    f"{w}x{h}",
                    "-r",
                    str(fps),
                    "-i",
                    "-",
                    "-vf",
                    "pad=ceil(iw/2)*2:ceil(ih/2)*2",
                    "-pix_fmt",
                    "yuv420p",
                    str(out),
                ],
                stdin=subprocess.PIPE,
            )
        proc.stdin.write(np.ascontiguousarray(rgb).tobytes())
        bar.update()
    if proc is not None:
        proc.stdin.close()
        if proc.wait() != 0:
            raise UserError(f"ffmpeg failed writing {out}")


DPI = 80
