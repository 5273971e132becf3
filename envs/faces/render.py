"""Top-view rendering of one scenario through matplotlib.

The drawing works on a *frame*: a dict of plain numbers and numpy arrays (:func:`frame_from_core`
builds one from a row of the core), so a replay tool can draw recorded frames with the same
:class:`TopView` (artists made once, moved per frame). :class:`Renderer` owns one figure and turns
frames into ``rgb_array`` images (Agg canvas, no pyplot state) or shows them (``human``, pyplot).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, cast

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from overtakezoo.envs.config import MODE_NAMES
from overtakezoo.envs.core import CRASH, OUTCOME_NAMES
from overtakezoo.envs.model.planner import lateral_profile
from overtakezoo.envs.scenarios import OPPOSITE_LANE

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from overtakezoo.envs.core import OvertakeCore

MODE_COLOURS = ("tab:blue", "tab:orange", "tab:purple")  # follow, overtake, abort


def frame_from_core(core: OvertakeCore, row: int = 0) -> dict[str, Any]:
    """Everything :func:`draw_frame` needs about ``row``, as plain Python / numpy values."""
    sc, pc = core.scen, core.cfg.planner
    assert sc is not None, "reset() first"
    p = core.last_plan
    frame = {
        "t": float(core.t[row]),
        "mode": int(core.mode[row]),
        "outcome": int(core.outcome[row]),
        "crash_npc": int(core.crash_npc[row]),
        "ego_x": float(core.x[row]),
        "ego_y": float(core.y[row]),
        "ego_psi": float(core.psi[row]),
        "ego_v": float(core.v[row]),
        "ego_length": float(sc.ego_length[row]),
        "ego_width": float(sc.ego_width[row]),
        "lane_width": float(sc.lane_width[row]),
        "goal_s": float(sc.goal_s[row]),
        "road_length": float(sc.road_length[row]),
        "sensor_range": float(sc.sensor_range[row]),
        "npc_present": sc.npc_present[row].copy(),
        "npc_lane": sc.npc_lane[row].copy(),
        "npc_s": core.npc_s[row].copy(),
        "npc_v": core.npc_v[row].copy(),
        "npc_length": sc.npc_length[row].copy(),
        "npc_width": sc.npc_width[row].copy(),
        "npc_reveal": sc.npc_reveal[row].copy(),
        # Rollouts: end offsets, blocked flags, the chosen index and the roll-in geometry.
        "roll_in": float(pc.roll_in_speed_factor * core.v[row] + pc.roll_in_margin),
        "tip_margin": float(pc.car_tip_margin),
        "horizon_time": float(pc.horizon_time),
    }
    if p is not None and p.offsets.shape[0] == core.num:
        frame.update(
            plan_offsets=p.offsets[row].copy(),
            plan_blocked=p.blocked[row].copy(),
            plan_rollout=int(p.rollout[row]),
            plan_target=float(p.target_d[row]),
        )
    return frame


def draw_frame(ax: Axes, frame: dict[str, Any]) -> TopView:
    """Draw ``frame`` on ``ax`` (a one-off :class:`TopView`; reuse the view to animate)."""
    view = TopView(ax)
    view.update(frame)
    return view


class TopView:
    """The top view on one axes, as persistent artists that :meth:`update` moves (no redraw of the
    axes per frame): road, lanes and centre line, goal, sensor range, rollouts (the chosen one bold,
    blocked ones red), vehicles as boxes (ego highlighted; vehicles the sensor does not see faded,
    the vehicle hit red), mode and time in the title.

    ``extent`` (left, right) fixes the x range (an overview of the whole road: ``aspect="auto"``
    stretches the lanes, boxes are not rotated); None follows the ego at equal aspect.
    """

    def __init__(self, ax: Axes, extent: tuple[float, float] | None = None, title: bool = True) -> None:
        from matplotlib.collections import LineCollection

        self.ax, self.extent, self.title = ax, extent, title
        self.rollouts: list[Any] = []  # Line2D per rollout, made at the first frame with a plan
        self.npcs: list[tuple[Rectangle, Any]] = []
        ax.set_facecolor("#6b8e4e")  # verge
        ax.set_aspect("auto" if extent else "equal")
        ax.set_yticks([])
        # (add_patch / add_collection return their argument; matplotlib's stubs type it as the base class)
        self.road = cast(Rectangle, ax.add_patch(Rectangle((-1e5, 0.0), 2e5, 1.0, color="#555555", zorder=0)))
        lines = lambda **kw: cast(LineCollection, ax.add_collection(LineCollection([], **kw)))  # noqa: E731
        self.edges = lines(colors="white", linewidths=1.5, zorder=1)
        self.centre = lines(colors="#f2c200", linestyles=(0, (6, 6)), linewidths=1.5, zorder=1)
        self.goal = lines(colors="white", linewidths=3, zorder=1)
        self.sensor = lines(colors="cyan", linestyles="dotted", linewidths=1.2, zorder=2)
        self.target = lines(colors="black", linestyles="--", linewidths=2.0, zorder=3)
        text: dict[str, Any] = dict(fontsize=7, clip_on=True)
        self.goal_text = ax.text(0, 0, "goal", ha="center", va="top", color="white", **text)
        self.sensor_text = ax.text(0, 0, "sensor range", ha="right", va="top", color="cyan", **text)
        # Lane names inside the axes (axes-fraction x, data y), so no label is cut at the figure edge.
        ytx = ax.get_yaxis_transform()
        self.lane_text = [
            ax.text(0.005, 0.0, "ego lane", transform=ytx, ha="left", va="center", color="white", fontsize=7, zorder=7),
            ax.text(
                0.005, 0.0, "opposite lane", transform=ytx, ha="left", va="center", color="white", fontsize=7, zorder=7
            ),
        ]
        self.ego = ax.add_patch(
            Rectangle((0, 0), 1, 1, rotation_point="center", edgecolor="yellow", linewidth=1.5, zorder=5)
        )
        self.ego_text = ax.text(
            0, 0, "ego", ha="center", va="center", fontsize=7, color="white", zorder=6, clip_on=True
        )
        self.title_text = ax.set_title("", fontsize=10, loc="left")  # the artist update() rewrites
        if extent:
            ax.set_xlim(*extent)
        if title:
            ax.set_xlabel("s (m)")

    def moving(self) -> list[Any]:
        """The artists :meth:`update` changes; the rest of the axes is the same in every frame of an
        episode (road, edges, lane names; in the overview also the ticks), so an animation can draw
        it once and blit these over it."""
        out = [] if self.extent else [self.centre, self.goal, self.goal_text]  # still in the overview
        out += [self.sensor, self.sensor_text, self.target, *self.rollouts]
        for box, label in self.npcs:
            out += [box, label]
        return out + [self.ego, self.ego_text, self.title_text]

    def _ensure(self, frame: dict[str, Any]) -> None:
        """Artists per NPC slot and per rollout (the counts are fixed for a given scenario layout)."""
        m = len(frame["npc_present"])
        while len(self.npcs) < m:
            box = cast(
                Rectangle,
                self.ax.add_patch(
                    Rectangle((0, 0), 1, 1, rotation_point="center", edgecolor="black", linewidth=1.5, zorder=5)
                ),
            )
            self.npcs.append(
                (box, self.ax.text(0, 0, "", ha="center", va="center", fontsize=7, zorder=6, clip_on=True))
            )
        for box, label in self.npcs[m:]:
            box.set_visible(False)
            label.set_visible(False)
        r = len(frame.get("plan_offsets", ()))
        while len(self.rollouts) < r:
            self.rollouts.append(self.ax.plot([], [], zorder=3)[0])

    def update(self, frame: dict[str, Any]) -> None:
        self._ensure(frame)
        ax = self.ax
        w, x0, y0 = frame["lane_width"], frame["ego_x"], frame["ego_y"]
        sensor = frame["sensor_range"]
        if self.extent:
            left, right = self.extent
        else:
            left, right = x0 - 15.0, x0 + min(max(sensor, 30.0), 100.0) + 5.0
            ax.set_xlim(left, right)
        bottom, top = -w / 2 - 1.0, 1.5 * w + 1.0
        ax.set_ylim(bottom, top)
        self.road.set_y(-w / 2)
        self.road.set_height(2 * w)
        span = (left - 1e4, right + 1e4)
        self.edges.set_segments([[(span[0], -w / 2), (span[1], -w / 2)], [(span[0], 1.5 * w), (span[1], 1.5 * w)]])
        self.centre.set_segments([[(span[0], w / 2), (span[1], w / 2)]])
        g = frame["goal_s"]
        self.goal.set_segments([[(g, -w / 2), (g, w / 2)]])
        self.goal_text.set_position((g, -w / 2 - 0.2))
        # Sensor range: vehicles farther than this (along the road) are invisible to decider and planner.
        self.sensor.set_segments([[(e, bottom), (e, top)] for e in (x0 - sensor, x0 + sensor)])
        # One line in the verge above the road, kept inside the view when the range reaches beyond it.
        self.sensor_text.set_position((min(x0 + sensor, right) - 0.3, top - 0.1))
        for text, y in zip(self.lane_text, (0.0, w), strict=True):
            text.set_y(y)

        # Rollouts ahead of the ego: each one's lateral profile, the chosen one bold.
        plan = "plan_offsets" in frame
        segments = []
        if plan:
            reach = max(frame["roll_in"] + frame["tip_margin"] + 10.0, frame["ego_v"] * frame["horizon_time"])
            ahead = np.linspace(0.0, reach, 40)
            ends = np.asarray(frame["plan_offsets"], dtype=float)
            ys = lateral_profile(y0, ends[:, None], ahead[None, :], w, frame["roll_in"], frame["tip_margin"])
            for k, (line, blocked) in enumerate(zip(self.rollouts, frame["plan_blocked"], strict=False)):
                chosen = k == frame["plan_rollout"]
                line.set_data(x0 + ahead, ys[k])
                line.set(
                    color="black" if chosen else ("#e04040" if blocked else "#60d060"),
                    linewidth=3.0 if chosen else 1.0,
                    alpha=1.0 if chosen else 0.8,
                    visible=True,
                )
            # An abort waiting for a gap tracks its current offset, not the chosen rollout's end (optional key).
            target = frame.get("plan_target")
            if target is not None and abs(target - ends[frame["plan_rollout"]]) > 0.01:
                ty = lateral_profile(y0, target, ahead, w, frame["roll_in"], frame["tip_margin"])
                segments = [np.stack([x0 + ahead, ty], axis=1)]
        else:
            for line in self.rollouts:
                line.set_visible(False)
        self.target.set_segments(segments)

        # Vehicles: NPCs (faded when the sensor does not see them, red when hit), then the ego.
        crash = frame["outcome"] == CRASH
        turn = 0.0 if self.extent else 1.0  # the stretched overview draws boxes unrotated
        # Half a label's width ("NPC1 ->", 7 pt) in metres at this view's scale, plus a margin.
        half_label = 20.0 * (right - left) / max(float(self.ax.bbox.width), 1.0)
        for j, (box, label) in enumerate(self.npcs[: len(frame["npc_present"])]):
            if not frame["npc_present"][j]:
                box.set_visible(False)
                label.set_visible(False)
                continue
            s, lane = float(frame["npc_s"][j]), int(frame["npc_lane"][j])
            length, width = float(frame["npc_length"][j]), float(frame["npc_width"][j])
            visible = abs(s - x0) <= min(sensor, float(frame["npc_reveal"][j]))
            hit = crash and frame["crash_npc"] == j
            if self.extent:  # the stretched overview: a box as wide as its label, so no edge crosses it
                length = max(length, 2.0 * half_label)
            box.set(
                xy=(s - length / 2, lane * w - width / 2),
                width=length,
                height=width,
                angle=float(np.degrees(np.pi if lane == OPPOSITE_LANE else 0.0)) * turn,
                facecolor="#d62728" if hit else "#bbbbbb",
                alpha=1.0 if visible or hit else 0.35,
                visible=True,
            )
            arrow = "\u2190" if lane == OPPOSITE_LANE else "\u2192"
            # A label near an edge of the view is anchored on its inner side, so it is never cut.
            ha = "left" if s - left < half_label else ("right" if right - s < half_label else "center")
            x = max(s, left + 0.3) if ha == "left" else (min(s, right - 0.3) if ha == "right" else s)
            label.set(
                position=(x, lane * w), text=f"NPC{j + 1} {arrow}", ha=ha, alpha=1.0 if visible else 0.4, visible=True
            )
        length, width = frame["ego_length"], frame["ego_width"]
        self.ego.set(
            xy=(x0 - length / 2, y0 - width / 2),
            width=length,
            height=width,
            angle=float(np.degrees(frame["ego_psi"])) * turn,
            facecolor=MODE_COLOURS[frame["mode"]],
        )
        self.ego_text.set_position((x0, y0))

        if self.title:
            ax.set_title(
                f"t = {frame['t']:5.1f} s    mode: {MODE_NAMES[frame['mode']].upper()}    "
                f"v = {frame['ego_v']:.2f} m/s    {OUTCOME_NAMES[frame['outcome']]}",
                fontsize=10,
                loc="left",
            )


class Renderer:
    """One reusable figure. ``rgb_array``: an Agg canvas outside pyplot (no global figure to leak);
    ``human``: a pyplot window refreshed with ``plt.pause`` (nothing is shown on a non-interactive
    backend such as Agg)."""

    def __init__(
        self, mode: str = "rgb_array", fps: float = 10.0, size: tuple[float, float] = (12.0, 2.4), dpi: int = 80
    ) -> None:
        if mode not in ("rgb_array", "human"):
            raise ValueError(f"render mode must be 'rgb_array' or 'human', got {mode!r}")
        self.mode, self.fps = mode, fps
        if mode == "human":
            import matplotlib.pyplot as plt

            self.fig: Figure | None = plt.figure(figsize=size, dpi=dpi)
        else:
            from matplotlib.backends.backend_agg import FigureCanvasAgg

            self.fig = Figure(figsize=size, dpi=dpi)
            FigureCanvasAgg(self.fig)
        self.ax = self.fig.add_subplot()
        self.view: TopView | None = None

    def render(self, frame: dict[str, Any]) -> np.ndarray | None:
        fig = self.fig
        assert fig is not None, "the renderer is closed"
        if self.view is None:
            self.view = TopView(self.ax)
            self.view.update(frame)
            fig.tight_layout()
        else:
            self.view.update(frame)
        if self.mode == "human":
            import matplotlib.pyplot as plt

            if _interactive():
                plt.pause(1.0 / self.fps)
            return None
        canvas = cast("FigureCanvasAgg", fig.canvas)  # rgb_array: the Agg canvas __init__ attached
        canvas.draw()
        return np.asarray(canvas.buffer_rgba())[..., :3].copy()

    def close(self) -> None:
        if self.mode == "human":
            import matplotlib.pyplot as plt

            plt.close(self.fig)
        self.fig = None


def _interactive() -> bool:
    import matplotlib
    from matplotlib.backends import BackendFilter, backend_registry

    return matplotlib.get_backend().lower() not in backend_registry.list_builtin(BackendFilter.NON_INTERACTIVE)


def render_rgb(core: OvertakeCore, row: int = 0, **kwargs: Any) -> np.ndarray:
    """One-off ``rgb_array`` image of ``row`` (creates and drops a figure; use :class:`Renderer` in loops)."""
    image = Renderer("rgb_array", **kwargs).render(frame_from_core(core, row))
    assert image is not None  # (rgb_array always returns one)
    return image
