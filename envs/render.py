"""Top-view rendering of one scenario through matplotlib.

The drawing works on a *frame*: a dict of plain numbers and numpy arrays (:func:`frame_from_core`
builds one from a row of the core), so a replay tool can draw recorded frames with the same
:func:`draw_frame`. :class:`Renderer` owns one figure and turns frames into ``rgb_array`` images
(Agg canvas, no pyplot state) or shows them (``human``, pyplot).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from .config import MODE_NAMES
from .core import CRASH, OUTCOME_NAMES
from .planner import lateral_profile
from .scenarios import OPPOSITE_LANE

if TYPE_CHECKING:
    from matplotlib.axes import Axes

    from .core import OvertakeCore

MODE_COLOURS = ("tab:blue", "tab:orange", "tab:purple")  # follow, overtake, abort


def frame_from_core(core: "OvertakeCore", row: int = 0) -> dict[str, Any]:
    """Everything :func:`draw_frame` needs about ``row``, as plain Python / numpy values."""
    sc, pc = core.scen, core.cfg.planner
    p = core.last_plan
    frame = {
        "t": float(core.t[row]), "mode": int(core.mode[row]), "outcome": int(core.outcome[row]),
        "crash_npc": int(core.crash_npc[row]),
        "ego_x": float(core.x[row]), "ego_y": float(core.y[row]), "ego_psi": float(core.psi[row]),
        "ego_v": float(core.v[row]), "ego_length": float(sc.ego_length[row]), "ego_width": float(sc.ego_width[row]),
        "lane_width": float(sc.lane_width[row]), "goal_s": float(sc.goal_s[row]),
        "road_length": float(sc.road_length[row]), "sensor_range": float(sc.sensor_range[row]),
        "npc_present": sc.npc_present[row].copy(), "npc_lane": sc.npc_lane[row].copy(),
        "npc_s": core.npc_s[row].copy(), "npc_v": core.npc_v[row].copy(),
        "npc_length": sc.npc_length[row].copy(), "npc_width": sc.npc_width[row].copy(),
        "npc_reveal": sc.npc_reveal[row].copy(),
        # Rollouts: end offsets, blocked flags, the chosen index and the roll-in geometry.
        "roll_in": float(pc.roll_in_speed_factor * core.v[row] + pc.roll_in_margin),
        "tip_margin": float(pc.car_tip_margin), "horizon_time": float(pc.horizon_time),
    }
    if p is not None and p.offsets.shape[0] == core.num:
        frame.update(plan_offsets=p.offsets[row].copy(), plan_blocked=p.blocked[row].copy(),
                     plan_rollout=int(p.rollout[row]), plan_target=float(p.target_d[row]))
    return frame


def draw_frame(ax: "Axes", frame: dict[str, Any]) -> None:
    """Draw ``frame`` on ``ax``: road, lanes and centre line, goal, sensor range, rollouts (the
    chosen one bold, blocked ones red), vehicles as oriented boxes (ego highlighted), mode and time."""
    w, x0, y0 = frame["lane_width"], frame["ego_x"], frame["ego_y"]
    sensor = frame["sensor_range"]
    left, right = x0 - 15.0, x0 + min(max(sensor, 30.0), 100.0) + 5.0
    bottom, top = -w / 2 - 1.0, 1.5 * w + 1.0
    ax.set_xlim(left, right)
    ax.set_ylim(bottom, top)
    ax.set_aspect("equal")
    ax.set_facecolor("#6b8e4e")  # verge

    # Road: both lanes, edges and the dashed centre line; the goal line.
    ax.add_patch(Rectangle((left, -w / 2), right - left, 2 * w, color="#555555", zorder=0))
    ax.hlines([-w / 2, 1.5 * w], left, right, colors="white", linewidth=1.5, zorder=1)
    ax.hlines([w / 2], left, right, colors="#f2c200", linestyles=(0, (6, 6)), linewidth=1.5, zorder=1)
    if left <= frame["goal_s"] <= right:
        ax.vlines(frame["goal_s"], -w / 2, w / 2, colors="white", linewidth=3, zorder=1)
        ax.text(frame["goal_s"], -w / 2 - 0.2, "goal", ha="center", va="top", fontsize=8, color="white")
    # Sensor range: vehicles farther than this (along the road) are invisible to decider and planner.
    for edge in (x0 - sensor, x0 + sensor):
        if left <= edge <= right:
            ax.vlines(edge, bottom, top, colors="cyan", linestyles="dotted", linewidth=1.2, zorder=2)
            ax.text(edge - 0.3, top - 0.1, "sensor\nrange", ha="right", va="top", fontsize=7, color="cyan")

    # Rollouts ahead of the ego: each one's lateral profile, the chosen one bold.
    if "plan_offsets" in frame:
        reach = max(frame["roll_in"] + frame["tip_margin"] + 10.0, frame["ego_v"] * frame["horizon_time"])
        ahead = np.linspace(0.0, reach, 40)
        for k, (end, blocked) in enumerate(zip(frame["plan_offsets"], frame["plan_blocked"])):
            ys = lateral_profile(y0, end, ahead, w, frame["roll_in"], frame["tip_margin"])
            chosen = k == frame["plan_rollout"]
            ax.plot(x0 + ahead, ys, color="black" if chosen else ("#e04040" if blocked else "#60d060"),
                    linewidth=3.0 if chosen else 1.0, alpha=1.0 if chosen else 0.8, zorder=3)
        # An abort waiting for a gap tracks its current offset, not the chosen rollout's end (optional key).
        target = frame.get("plan_target")
        if target is not None and abs(target - frame["plan_offsets"][frame["plan_rollout"]]) > 0.01:
            ys = lateral_profile(y0, target, ahead, w, frame["roll_in"], frame["tip_margin"])
            ax.plot(x0 + ahead, ys, color="black", linewidth=2.0, linestyle="--", zorder=3)

    # Vehicles: NPCs (faded when outside the sensor range), then the ego.
    for j in np.flatnonzero(frame["npc_present"]):
        s, lane = float(frame["npc_s"][j]), int(frame["npc_lane"][j])
        length, width = float(frame["npc_length"][j]), float(frame["npc_width"][j])
        visible = abs(s - x0) <= min(sensor, float(frame["npc_reveal"][j]))
        crashed = frame["outcome"] == CRASH and frame["crash_npc"] == j
        heading = np.pi if lane == OPPOSITE_LANE else 0.0
        _box(ax, s, lane * w, heading, length, width, "#d62728" if crashed else "#bbbbbb", visible)
        arrow = "\u2190" if lane == OPPOSITE_LANE else "\u2192"
        ax.text(s, lane * w, f"NPC{j + 1} {arrow}", ha="center", va="center", fontsize=7,
                alpha=1.0 if visible else 0.4, zorder=6)
    _box(ax, x0, y0, frame["ego_psi"], frame["ego_length"], frame["ego_width"],
         MODE_COLOURS[frame["mode"]], True, edge="yellow")
    ax.text(x0, y0, "ego", ha="center", va="center", fontsize=7, color="white", zorder=6)

    outcome = OUTCOME_NAMES[frame["outcome"]]
    ax.set_title(f"t = {frame['t']:5.1f} s    mode: {MODE_NAMES[frame['mode']].upper()}    "
                 f"v = {frame['ego_v']:.2f} m/s    {outcome}", fontsize=10, loc="left")
    ax.set_xlabel("s (m)")
    ax.set_yticks([0.0, w], ["ego lane", "opposite"], fontsize=8)


def _box(ax: "Axes", x: float, y: float, psi: float, length: float, width: float, colour: str,
         visible: bool, edge: str = "black") -> None:
    ax.add_patch(Rectangle((x - length / 2, y - width / 2), length, width, angle=float(np.degrees(psi)),
                           rotation_point="center", facecolor=colour, edgecolor=edge,
                           linewidth=1.5, alpha=1.0 if visible else 0.35, zorder=5))


class Renderer:
    """One reusable figure. ``rgb_array``: an Agg canvas outside pyplot (no global figure to leak);
    ``human``: a pyplot window refreshed with ``plt.pause`` (nothing is shown on a non-interactive
    backend such as Agg)."""

    def __init__(self, mode: str = "rgb_array", fps: float = 10.0, size: tuple[float, float] = (12.0, 2.4),
                 dpi: int = 80) -> None:
        if mode not in ("rgb_array", "human"):
            raise ValueError(f"render mode must be 'rgb_array' or 'human', got {mode!r}")
        self.mode, self.fps = mode, fps
        if mode == "human":
            import matplotlib.pyplot as plt

            self.fig = plt.figure(figsize=size, dpi=dpi)
        else:
            from matplotlib.backends.backend_agg import FigureCanvasAgg

            self.fig = Figure(figsize=size, dpi=dpi)
            FigureCanvasAgg(self.fig)
        self.ax = self.fig.add_subplot()

    def render(self, frame: dict[str, Any]) -> np.ndarray | None:
        self.ax.clear()
        draw_frame(self.ax, frame)
        self.fig.tight_layout()
        if self.mode == "human":
            import matplotlib.pyplot as plt

            if _interactive():
                plt.pause(1.0 / self.fps)
            return None
        self.fig.canvas.draw()
        return np.asarray(self.fig.canvas.buffer_rgba())[..., :3].copy()

    def close(self) -> None:
        if self.mode == "human":
            import matplotlib.pyplot as plt

            plt.close(self.fig)
        self.fig = None


def _interactive() -> bool:
    import matplotlib
    from matplotlib.backends import BackendFilter, backend_registry

    return matplotlib.get_backend().lower() not in backend_registry.list_builtin(BackendFilter.NON_INTERACTIVE)


def render_rgb(core: "OvertakeCore", row: int = 0, **kwargs: Any) -> np.ndarray:
    """One-off ``rgb_array`` image of ``row`` (creates and drops a figure; use :class:`Renderer` in loops)."""
    return Renderer("rgb_array", **kwargs).render(frame_from_core(core, row))
