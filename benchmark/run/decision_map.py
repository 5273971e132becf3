"""The paper's Fig. 10 for any decider: the mode it picks over a grid of NPC1 gap x NPC2 distance.

Each grid cell is a hand-made scenario (fixed speeds); the whole grid is one batch, reset once, and
the decider is shown the first observation for ``ticks`` decision ticks (stateful deciders such as
rule-fsm commit only after several consistent ticks); the map shows the last mode. By default one
FOLLOW step (0.1 s, vehicles move < 0.5 m) runs first: the very first observation carries no planner
flags yet (the planner has not evaluated the scene), and rule deciders act on those flags.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from typing import Any

import numpy as np

from overtakezoo.envs import MODE_NAMES, OvertakeCore, Scenarios, make_scenario

# Road keys of a suite's distribution that a hand-made scenario takes over.
ROAD_KEYS = (
    "speed_limit",
    "lane_width",
    "goal",
    "road_extra",
    "sensor_range",
    "time_limit",
    "ego_length",
    "ego_width",
    "vehicle_length",
    "vehicle_width",
)
COLOURS = ("#4c72b0", "#55a868", "#c44e52")  # follow, overtake, abort


@dataclass
class DecisionMap:
    gaps: np.ndarray  # (G,) NPC1 bumper gap, m
    distances: np.ndarray  # (D,) ego front to NPC2 front, m
    modes: np.ndarray  # (G, D) int
    lead_speed: float
    oncoming_speed: float
    decider: str
    suite: str


def decision_map(
    decider: Any,
    suite: Any,
    gaps: np.ndarray,
    distances: np.ndarray,
    lead_speed: float = 2.0,
    oncoming_speed: float = 2.0,
    ticks: int = 4,
    warmup: int = 1,
) -> DecisionMap:
    road = {k: getattr(suite.distribution, k) for k in ROAD_KEYS}
    ego_speed = suite.distribution.ego_speed[1]
    cells = [
        make_scenario(lead=(float(g), lead_speed), oncoming=[(float(d), oncoming_speed)], ego_speed=ego_speed, **road)
        for g in gaps
        for d in distances
    ]
    batch = Scenarios.concat(cells)
    core = OvertakeCore(suite.config)
    obs = core.reset(batch)
    decider.reset()
    if getattr(decider, "privileged", False):
        decider.bind(core)
    for _ in range(warmup):
        obs = core.step(np.zeros(batch.num, np.int64)).obs
    for _ in range(max(1, ticks)):
        modes = decider.act(obs)
    modes = np.asarray(modes, dtype=np.int64).reshape(len(gaps), len(distances))
    return DecisionMap(
        np.asarray(gaps, float),
        np.asarray(distances, float),
        modes,
        lead_speed,
        oncoming_speed,
        decider.name,
        suite.name,
    )


# What ``plot`` writes, by the output file's suffix: matplotlib's format name and the metadata that keeps
# the bytes free of timestamps and version strings (JPEG: Pillow, a dependency of matplotlib).
FORMATS: dict[str, tuple[str, dict[str, Any] | None]] = {
    ".png": ("png", {"Software": None}),
    ".jpg": ("jpeg", None),
    ".jpeg": ("jpeg", None),
    ".svg": ("svg", {"Date": None}),
    ".pdf": ("pdf", {"CreationDate": None, "Producer": None}),
}


def image_format(suffix: str) -> str:
    """The format an output file's suffix names (no suffix: PNG); ValueError naming the supported ones."""
    suffix = suffix.lower() or ".png"
    if suffix not in FORMATS:
        raise ValueError(f"cannot write a {suffix} image: supported suffixes are {', '.join(FORMATS)}")
    return FORMATS[suffix][0]


def plot(dm: DecisionMap, fmt: str = "png") -> bytes:
    """The map as image bytes in ``fmt`` (png, jpeg, svg or pdf; Agg canvas, no timestamps: identical
    bytes for identical maps)."""
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import ListedColormap
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch

    by_name = dict(FORMATS.values())
    if fmt not in by_name:
        raise ValueError(f"unsupported image format {fmt!r} (supported: {', '.join(by_name)})")
    with matplotlib.rc_context({"font.family": "DejaVu Sans", "font.size": 9, "svg.hashsalt": "overtakezoo"}):
        fig = Figure(figsize=(6.0, 4.5), dpi=100)
        FigureCanvasAgg(fig)
        ax = fig.add_subplot(1, 1, 1)
        half_d = (dm.distances[1] - dm.distances[0]) / 2 if len(dm.distances) > 1 else 1.0
        half_g = (dm.gaps[1] - dm.gaps[0]) / 2 if len(dm.gaps) > 1 else 1.0
        extent = (dm.distances[0] - half_d, dm.distances[-1] + half_d, dm.gaps[0] - half_g, dm.gaps[-1] + half_g)
        ax.imshow(
            dm.modes,
            origin="lower",
            aspect="auto",
            extent=extent,
            cmap=ListedColormap(COLOURS),
            vmin=-0.5,
            vmax=2.5,
            interpolation="nearest",
        )
        ax.set_xlabel("NPC2 (oncoming) distance from the ego's front (m)")
        ax.set_ylabel("NPC1 (lead) gap D1 (m)")
        ax.set_title(
            f"{dm.decider} on {dm.suite}: mode at the first decision\n"
            f"(NPC1 {dm.lead_speed:g} m/s, NPC2 {dm.oncoming_speed:g} m/s)"
        )
        ax.legend(
            handles=[Patch(color=c, label=n) for c, n in zip(COLOURS, MODE_NAMES, strict=True)],
            loc="upper right",
            fontsize=8,
            framealpha=0.9,
        )
        fig.tight_layout()
        buf = io.BytesIO()
        fig.savefig(buf, format=fmt, metadata=by_name[fmt])
    return buf.getvalue()
