"""Replay an archived episode from the MCAP file alone: frames for the render-mode top view.

Frames are the dicts :func:`overtakezoo.envs.render.draw_frame` draws (the same view as
``render_mode``); a GIF goes through matplotlib's pillow writer, an MP4 needs ``ffmpeg`` on PATH,
a PNG is the final frame.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from overtakezoo.envs import OUTCOME_NAMES, PlannerConfig

from .archive import Episode, read_archive_meta, read_episode
from .errors import UserError
from .io import atomic_path

RUNNING = 0


def _planner(meta: dict[str, str]) -> dict[str, float]:
    """The planner geometry the drawing needs, from the config stored in the archive."""
    defaults = PlannerConfig()
    stored = json.loads(meta.get("config", "{}")).get("planner", {}) or {}
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
            "t": float(ep.t[k]), "mode": int(ep.mode[k - 1]) if k else 0,
            "outcome": outcome if k == last else RUNNING, "crash_npc": crash_npc if k == last else -1,
            "ego_x": float(ep.ego["x"][k]), "ego_y": float(ep.ego["y"][k]), "ego_psi": float(ep.ego["psi"][k]),
            "ego_v": v, "ego_length": float(sc["ego_length"]), "ego_width": float(sc["ego_width"]),
            "lane_width": float(sc["lane_width"]), "goal_s": float(sc["goal_s"]),
            "road_length": float(sc["road_length"]), "sensor_range": float(sc["sensor_range"]),
            "npc_present": arr("npc_present", bool), "npc_lane": arr("npc_lane", np.int8),
            "npc_s": ep.npc_s[k], "npc_v": ep.npc_v[k], "npc_length": arr("npc_length"),
            "npc_width": arr("npc_width"), "npc_reveal": arr("npc_reveal"),
            "roll_in": pc["roll_in_speed_factor"] * v + pc["roll_in_margin"],
            "tip_margin": pc["car_tip_margin"], "horizon_time": pc["horizon_time"],
        }
        if k:
            frame.update(plan_offsets=ep.offsets[k - 1], plan_blocked=ep.blocked[k - 1],
                         plan_rollout=int(ep.rollout[k - 1]))
        frames.append(frame)
    return frames


def replay(path: str | Path, episode: int, out: str | Path, fps: float = 10.0, every: int = 1) -> Path:
    """Render episode ``episode`` of archive ``path`` to ``out`` (.gif, .mp4 or .png)."""
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix not in (".gif", ".mp4", ".png"):
        raise UserError(f"--out must end in .gif, .mp4 or .png, got {out.name!r}")
    if suffix == ".mp4" and shutil.which("ffmpeg") is None:
        raise UserError("writing .mp4 needs ffmpeg on PATH (not found); use --out ep.gif instead")
    ep = read_episode(path, episode)
    frames = episode_frames(ep, read_archive_meta(path), every=1 if suffix == ".png" else every)

    from matplotlib.animation import FFMpegWriter, FuncAnimation, PillowWriter
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from overtakezoo.envs.render import draw_frame

    fig = Figure(figsize=(12.0, 3.2), dpi=80)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()

    def draw(i: int) -> list:
        ax.clear()
        draw_frame(ax, frames[i])
        for text in ax.texts:  # labels of vehicles off-screen would otherwise land beside the axes
            text.set_clip_on(True)
        ax.set_title(ax.get_title(loc="left") + f"    episode {ep.index}", fontsize=10, loc="left")
        return []

    try:
        with atomic_path(out) as tmp:  # a temp file beside out, renamed when complete
            if suffix == ".png":
                draw(len(frames) - 1)
                fig.tight_layout()
                fig.savefig(tmp)
            else:
                fig.tight_layout()
                anim = FuncAnimation(fig, draw, frames=len(frames), blit=False)
                writer = PillowWriter(fps=fps) if suffix == ".gif" else FFMpegWriter(fps=fps)
                anim.save(tmp, writer=writer)
    except OSError as exc:
        raise UserError(f"cannot write {out}: {exc.strerror or exc}") from None
    return out
