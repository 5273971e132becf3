"""The Foxglove scene of an archive: ``/tf`` (``foxglove_msgs/FrameTransforms``) and the
``/scene/*`` topics (``foxglove_msgs/SceneUpdate``), CDR-encoded from numpy (:mod:`.cdr`).

Static geometry is drawn once in its own frame, and only the frames move: at every scene step
``/tf`` places ``ego`` (with its yaw) and ``npc1..npcM``. The SceneUpdates are written when what they show changes:
``/scene/road`` at the episode's first step; ``/scene/vehicles`` (one cube per vehicle, locked to
its frame) at the first step, when the sensor starts or stops seeing an NPC, and at the final step
(the vehicle hit in magenta); ``/scene/rollouts`` (in the ``ego`` frame, so they move with the ego
at every step) at the first and final steps, when the chosen rollout or a blocked flag changes, and
otherwise every ``ROLLOUT_EVERY`` steps (their shape follows the ego's lateral offset, speed and
heading, which change at almost every step: redrawing them at every step would be most of the
archive's bytes; between redraws they turn with the ego); ``/scene/label`` when the mode changes; ``/scene/outcome``
clears the previous episode's outcome at the first step and shows this one's at the final step.
Foxglove keeps each entity until it is replaced (same id on the same topic), so after a seek every
topic's latest message is the whole picture. Display precision only: the state topic is exact.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from overtakezoo.benchmark.archive.cdr import Layout
from overtakezoo.envs import CRASH, MODE_NAMES, OUTCOME_NAMES

ROLLOUT_DRAW_M = 30.0  # rollouts are drawn this far ahead of the ego
ROLLOUT_EVERY = 10  # steps between rollout redraws when neither the choice nor a blocked flag changes
LABEL_WIDTH = 28  # the label text is padded to this many bytes (fixed-size messages)
OUTCOME_WIDTH = 24


def rollout_geometry(
    pc: Any, x: np.ndarray, y: np.ndarray, v: np.ndarray, w: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(n, R, 4) x and y of each rollout's drawn corners for states (x, y, v) on lanes of width w.

    Recomputed from the recorded state at write time (elementwise, so the same numbers as at the
    step) instead of being captured per step: the capture stays a few numbers per row and step."""
    from overtakezoo.envs.model.planner import lateral_profile

    y, v, w = y[:, None], v[:, None], w[:, None]
    roll_in = pc.roll_in_speed_factor * v + pc.roll_in_margin
    targets = w * (np.arange(pc.num_rollouts + 1) / pc.num_rollouts)[None, :]  # (n, R)
    # Each rollout's lateral profile is piecewise linear (hold, ramp, end offset): its corners
    # within the first ROLLOUT_DRAW_M metres draw it exactly with four points.
    ramp_end = np.minimum(pc.car_tip_margin + np.abs(targets - y) * roll_in / w, ROLLOUT_DRAW_M)
    ahead = np.stack(
        np.broadcast_arrays(0.0, min(pc.car_tip_margin, ROLLOUT_DRAW_M), ramp_end, ROLLOUT_DRAW_M), axis=-1
    )  # (n, R, 4)
    lat = lateral_profile(y[..., None], targets[..., None], ahead, w[..., None], roll_in[..., None], pc.car_tip_margin)
    return x[:, None, None] + ahead, lat


# ---------------------------------------------------------------------------- layouts
def _time(lay: Layout, name: str) -> None:
    lay.slot(f"{name}_sec", "<u4").slot(f"{name}_nsec", "<u4")


def _pose(lay: Layout, name: str | None, z: float = 0.0) -> None:
    """Position (x, y slots or constants 0), z constant, orientation identity (or a yaw slot)."""
    if name is None:
        lay.f8(0.0, 0.0, z, 0.0, 0.0, 0.0, 1.0)
    else:
        lay.slot(f"{name}_xy", "<f8", 2).f8(z, 0.0, 0.0, 0.0, 1.0)


def _color(lay: Layout, name: str | None, rgba: tuple[float, ...] = ()) -> None:
    lay.slot(f"{name}_rgba", "<f8", 4) if name else lay.f8(*rgba)


def _entity(
    lay: Layout, k: int, frame: str, eid: str, cubes: int = 0, lines: int = 0, texts: int = 0, locked: bool = False
) -> None:
    """A SceneEntity's head (its primitives follow in the caller, in schema order)."""
    _time(lay, f"e{k}")
    lay.string(frame).string(eid).u4(0, 0).u1(int(locked))
    lay.u4(0).u4(0)  # metadata, arrows
    lay.u4(cubes)


def _after_cubes(lay: Layout, lines: int) -> None:
    lay.u4(0).u4(0)  # spheres, cylinders
    lay.u4(lines)


def _after_lines(lay: Layout, texts: int) -> None:
    lay.u4(0)  # triangles
    lay.u4(texts)


def _end_entity(lay: Layout) -> None:
    lay.u4(0)  # models


def road_layout(ch: int) -> Layout:
    lay = Layout(ch).u4(0).u4(1)  # no deletions, one entity
    _entity(lay, 0, "map", "road", cubes=4)
    for j in range(4):  # lane, opposite lane, centre line, goal line
        _pose(lay, f"c{j}", z=[-0.05, -0.05, 0.0, 0.01][j])
        lay.slot(f"c{j}_size", "<f8", 3)
        _color(lay, None, [(0.25, 0.25, 0.25, 1), (0.3, 0.3, 0.3, 1), (1, 1, 1, 1), (0.1, 0.8, 0.1, 1)][j])
    _after_cubes(lay, 0)
    _after_lines(lay, 0)
    _end_entity(lay)
    return lay


def vehicles_layout(ch: int, m: int) -> Layout:
    lay = Layout(ch).u4(0).u4(1 + m)
    for k, frame in enumerate(["ego"] + [f"npc{j + 1}" for j in range(m)]):
        _entity(lay, k, frame, frame, cubes=1, locked=True)
        _pose(lay, None, z=0.75)
        lay.slot(f"v{k}_size", "<f8", 2).f8(1.5)
        _color(lay, f"v{k}")
        _after_cubes(lay, 0)
        _after_lines(lay, 0)
        _end_entity(lay)
    return lay


def rollouts_layout(ch: int, r: int) -> Layout:
    lay = Layout(ch).u4(0).u4(1)
    _entity(lay, 0, "ego", "rollouts", locked=True)
    _after_cubes(lay, r)
    for j in range(r):
        lay.u1(0)  # LINE_STRIP
        _pose(lay, None)
        lay.slot(f"l{j}_thick", "<f8").u1(0)  # thickness, scale_invariant
        lay.u4(4)
        for p in range(4):
            lay.slot(f"l{j}_p{p}", "<f8", 2).f8(0.05)
        _color(lay, f"l{j}")
        lay.u4(0).u4(0)  # colors, indices
    _after_lines(lay, 0)
    _end_entity(lay)
    return lay


def _text_layout(ch: int, eid: str, z: float, size: float, width: int, colour: bool) -> Layout:
    lay = Layout(ch).u4(0).u4(1)
    _entity(lay, 0, "ego", eid, locked=True)
    _after_cubes(lay, 0)
    _after_lines(lay, 1)
    _pose(lay, None, z=z)
    lay.u1(1).f8(size).u1(1)  # billboard, font_size, scale_invariant
    _color(lay, "text" if colour else None, (1, 1, 1, 1))
    lay.text("text", width)
    _end_entity(lay)
    return lay


def clear_layout(ch: int) -> Layout:
    """A SceneUpdate deleting every entity of its topic (the previous episode's outcome)."""
    lay = Layout(ch).u4(1)
    _time(lay, "d")
    lay.u1(1).string("")  # ALL
    return lay.u4(0)


def tf_layout(ch: int, m: int) -> Layout:
    lay = Layout(ch).u4(1 + m)
    for k, child in enumerate(["ego"] + [f"npc{j + 1}" for j in range(m)]):
        _time(lay, f"t{k}")
        lay.string("map").string(child)
        lay.slot(f"t{k}_xy", "<f8", 2).f8(0.0)
        if k == 0:
            lay.f8(0.0, 0.0).slot("yaw_zw", "<f8", 2)
        else:
            lay.f8(0.0, 0.0, 0.0, 1.0)
    return lay


class SceneLayouts:
    """The layouts of one file's scene (its channels, NPC slots M and rollouts R)."""

    def __init__(self, channels: dict[str, int], m: int, r: int) -> None:
        self.m, self.r = m, r
        self.tf = tf_layout(channels["/tf"], m)
        self.road = road_layout(channels["/scene/road"])
        self.vehicles = vehicles_layout(channels["/scene/vehicles"], m)
        self.rollouts = rollouts_layout(channels["/scene/rollouts"], r)
        self.label = _text_layout(channels["/scene/label"], "label", 3.0, 14.0, LABEL_WIDTH, False)
        self.clear = clear_layout(channels["/scene/outcome"])
        self.outcome = _text_layout(channels["/scene/outcome"], "outcome", 5.0, 28.0, OUTCOME_WIDTH, True)


# ---------------------------------------------------------------------------- colours
_ORANGE, _RED_CAR, _UNSEEN, _HIT, _NONE = (
    (1, 0.6, 0.1, 1),
    (0.9, 0.1, 0.1, 1),
    (0.6, 0.6, 0.6, 0.3),
    (1, 0, 1, 1),
    (0, 0, 0, 0),
)
_BLUE = (0.1, 0.4, 1, 1)
_LINE = np.array([(0.1, 0.9, 0.1, 1), (0.9, 0.2, 0.2, 0.6), (0.8, 0.8, 0.8, 0.5)])  # chosen, blocked, free
_OUTCOME_COLOUR = {"crash": _HIT, "success": (0.1, 0.9, 0.1, 1)}


def _times(lay: Layout, recs: np.ndarray, ns: np.ndarray, prefixes: list[str]) -> None:
    recs["log_time"] = recs["publish_time"] = ns
    sec, nsec = ns // 10**9, ns % 10**9
    for p in prefixes:
        recs[f"{p}_sec"], recs[f"{p}_nsec"] = sec, nsec


def scene_records(
    lay: SceneLayouts, pc: Any, s: dict[str, np.ndarray], e: dict[str, np.ndarray]
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Every scene record of a group of episodes, as (records, scene-row index) per kind.

    ``s``: per scene row (episode-major, steps increasing): ``ep`` (group-local episode), ``ns``,
    ``first``, ``final``, ``k`` (step), x, y, psi, v, npc_s (n, M), mode, chosen, blocked (n, R).
    ``e``: per episode: lane_width, road_length, goal_s, npc_s0 (initial positions), ego_length,
    ego_width, npc_lane, npc_length, npc_width, npc_present, sensor_range, npc_reveal, outcome,
    crash_npc, index (global)."""
    n, m, r = len(s["ns"]), lay.m, lay.r
    ep, first, final = s["ep"], s["first"], s["final"]
    w = e["lane_width"][ep]
    x, y = s["x"], s["y"]
    # change points, within each episode (the first row always counts)
    prev = np.concatenate([[0], np.arange(n - 1)])
    out = []

    tf = lay.tf.fill(n)
    _times(lay.tf, tf, s["ns"], [f"t{k}" for k in range(1 + m)])
    tf["t0_xy"] = np.stack([x, y], 1)
    tf["yaw_zw"] = np.stack([np.sin(s["psi"] / 2), np.cos(s["psi"] / 2)], 1)
    for j in range(m):
        tf[f"t{1 + j}_xy"] = np.stack([s["npc_s"][:, j], e["npc_lane"][ep, j] * w], 1)
    out.append((tf, np.arange(n)))

    rows = np.flatnonzero(first)
    ee = ep[rows]
    lo = np.minimum(-20.0, e["npc_s0"].min(axis=1) - 20.0)[ee]
    length, wr = e["road_length"][ee], e["lane_width"][ee]
    mid, span = (lo + length) / 2, length - lo
    road = lay.road.fill(len(rows))
    _times(lay.road, road, s["ns"][rows], ["e0"])
    for j, (cx, cy, sx, sy) in enumerate(
        [
            (mid, 0 * wr, span, wr),
            (mid, wr, span, wr),
            (mid, wr / 2, span, 0.15 + 0 * wr),
            (e["goal_s"][ee], 0 * wr, 0.3 + 0 * wr, wr),
        ]
    ):
        road[f"c{j}_xy"] = np.stack([cx, cy], 1)
        road[f"c{j}_size"] = np.stack([sx, sy, np.full(len(rows), 0.1 if j < 2 else 0.02)], 1)
    out.append((road, rows))

    # Vehicles: own lane orange, oncoming red, out of the ego's sight grey and translucent; the
    # colours are worked out for the rows written only (where the sight of some NPC changes).
    reach = np.minimum(e["sensor_range"][:, None], e["npc_reveal"])[ep]
    seen = np.abs(s["npc_s"] - x[:, None]) <= reach
    rows = np.flatnonzero(first | final | (seen != seen[prev]).any(axis=1))
    ee, seen = ep[rows], seen[rows, :, None]
    own = (e["npc_lane"][ee] == 0)[..., None]
    rgba = np.where(seen, np.where(own, np.array(_ORANGE), np.array(_RED_CAR)), np.array(_UNSEEN))
    hit = final[rows] & (e["outcome"][ee] == CRASH)
    hit_slot = np.zeros((len(rows), m), bool)
    hit_slot[hit] = np.arange(m)[None, :] == e["crash_npc"][ee[hit], None]
    rgba = np.where(hit_slot[..., None], np.array(_HIT), rgba)
    rgba = np.where(e["npc_present"][ee][..., None], rgba, np.array(_NONE))
    veh = lay.vehicles.fill(len(rows))
    _times(lay.vehicles, veh, s["ns"][rows], [f"e{k}" for k in range(1 + m)])
    veh["v0_size"] = np.stack([e["ego_length"][ee], e["ego_width"][ee]], 1)
    veh["v0_rgba"] = _BLUE
    for j in range(m):
        veh[f"v{j + 1}_size"] = np.stack([e["npc_length"][ee, j], e["npc_width"][ee, j]], 1)
        veh[f"v{j + 1}_rgba"] = rgba[:, j]
    out.append((veh, rows))

    chosen, blocked = s["chosen"], s["blocked"]
    redraw = (
        (s["k"] // ROLLOUT_EVERY != s["k"][prev] // ROLLOUT_EVERY)
        | (chosen != chosen[prev])
        | (blocked != blocked[prev]).any(axis=1)
    )
    rows = np.flatnonzero(first | final | redraw)
    rx, ry = rollout_geometry(pc, x[rows], y[rows], s["v"][rows], w[rows])
    ro = lay.rollouts.fill(len(rows))
    _times(lay.rollouts, ro, s["ns"][rows], ["e0"])
    is_chosen = np.arange(r)[None, :] == chosen[rows, None]
    style = np.where(is_chosen, 0, np.where(blocked[rows], 1, 2))
    dx, dy = rx - x[rows, None, None], ry - y[rows, None, None]  # into the ego frame (its yaw at this step)
    c, sn = np.cos(s["psi"][rows])[:, None, None], np.sin(s["psi"][rows])[:, None, None]
    px, py = c * dx + sn * dy, c * dy - sn * dx
    for j in range(r):
        ro[f"l{j}_thick"] = np.where(is_chosen[:, j], 0.25, 0.10)
        ro[f"l{j}_rgba"] = _LINE[style[:, j]]
        for p in range(4):
            ro[f"l{j}_p{p}"] = np.stack([px[:, j, p], py[:, j, p]], 1)
    out.append((ro, rows))

    mode = s["mode"]
    rows = np.flatnonzero(first | final | (mode != mode[prev]))
    lab = lay.label.fill(len(rows))
    _times(lay.label, lab, s["ns"][rows], ["e0"])
    names = np.array([n_.ljust(8).encode() for n_ in MODE_NAMES])
    lab["text"] = np.char.add(
        np.char.add(b"episode ", np.char.ljust(e["index"][ep[rows]].astype("S12"), 10)), names[mode[rows]]
    )
    lab["text"] = np.char.ljust(lab["text"], LABEL_WIDTH)  # numpy pads with NUL: pad with spaces
    out.append((lab, rows))

    rows = np.flatnonzero(first)
    clr = lay.clear.fill(len(rows))
    _times(lay.clear, clr, s["ns"][rows], ["d"])
    out.append((clr, rows))
    rows = np.flatnonzero(final)
    ee = ep[rows]
    oc = lay.outcome.fill(len(rows))
    _times(lay.outcome, oc, s["ns"][rows], ["e0"])
    words, colours = [], []
    for o, h in zip(e["outcome"][ee].tolist(), e["crash_npc"][ee].tolist(), strict=True):  # one per episode
        name = OUTCOME_NAMES[o]
        words.append((name.upper() + (f" with NPC{h + 1}" if o == CRASH and h >= 0 else "")).encode())
        colours.append(_OUTCOME_COLOUR.get(name, _ORANGE))
    oc["text"] = [x.ljust(OUTCOME_WIDTH)[:OUTCOME_WIDTH] for x in words]
    oc["text_rgba"] = colours
    out.append((oc, rows))
    return out
