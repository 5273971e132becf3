"""The Foxglove scene of an archive: ``/scene`` (``foxglove.SceneUpdate``) and ``/tf`` messages.

The recorder captures the state per step and, per episode, :func:`scene_messages`
fills one %-template per episode with every step's numbers (road and vehicle sizes built in;
display precision only: the state topics are exact).
"""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np

from overtakezoo.envs import CRASH, MODE_NAMES, OUTCOME_NAMES

ROLLOUT_DRAW_M = 30.0  # rollouts are drawn this far ahead of the ego in the Foxglove scene


def rollout_geometry(pc: Any, x: np.ndarray, y: np.ndarray, v: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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
    ahead = np.stack(np.broadcast_arrays(0.0, min(pc.car_tip_margin, ROLLOUT_DRAW_M), ramp_end,
                                         ROLLOUT_DRAW_M), axis=-1)  # (n, R, 4)
    lat = lateral_profile(y[..., None], targets[..., None], ahead, w[..., None], roll_in[..., None],
                          pc.car_tip_margin)
    return x[:, None, None] + ahead, lat


def scene_messages(ep: int, base: int, r: int, scen: dict[str, np.ndarray], ks: np.ndarray,
                    ego: np.ndarray, npc_s: np.ndarray, cap: dict[str, np.ndarray],
                    final: tuple[int, int] | None, dt_ns: int, sc_ch: Any, tf_ch: Any) -> list[tuple[int, int, bytes]]:
    """foxglove.SceneUpdate + FrameTransform of one episode's scene steps ``ks``, through one
    %-template per episode (its road and vehicle sizes built in; display precision: mm).
    ``final`` (outcome, crash_npc) when ``ks`` ends at the episode's final step: that update
    shows the outcome and the vehicle hit."""
    w, length, goal = float(scen["lane_width"][r]), float(scen["road_length"][r]), float(scen["goal_s"][r])
    lo = min(-20.0, float(np.min(scen["npc_s"][r])) - 20.0)
    mid, span = (lo + length) / 2, length - lo
    road = ",".join([_CUBE_FMT % (mid, 0.0, -0.05, 0.0, 1.0, span, w, 0.1, _ROAD),
                     _CUBE_FMT % (mid, w, -0.05, 0.0, 1.0, span, w, 0.1, _ROAD_OPP),
                     _CUBE_FMT % (mid, w / 2, 0.0, 0.0, 1.0, span, 0.15, 0.02, _WHITE),
                     _CUBE_FMT % (goal, 0.0, 0.01, 0.0, 1.0, 0.3, w, 0.02, _GOAL)])
    # Vehicles: the ego (x, y, yaw vary), then each present NPC (x and colour vary).
    size = f'"size":{{"x":{float(scen["ego_length"][r]):.3f},"y":{float(scen["ego_width"][r]):.3f},"z":1.500}}'
    cubes = ['{"pose":{"position":{"x":%.3f,"y":%.3f,"z":0.750},"orientation":{"x":0.0,"y":0.0,"z":%.6f,'
             f'"w":%.6f}}}},{size},"color":{_BLUE}}}']
    present = np.flatnonzero(scen["npc_present"][r])
    lanes = scen["npc_lane"][r][present]
    for j in present.tolist():
        cubes.append('{"pose":{"position":{"x":%.3f,' + f'"y":{int(scen["npc_lane"][r][j]) * w:.3f},"z":0.750}},'
                     f'"orientation":{_QID}}},"size":{{"x":{float(scen["npc_length"][r][j]):.3f},'
                     f'"y":{float(scen["npc_width"][r][j]):.3f},"z":1.500}},"color":%s}}')
    n_ro = cap["blocked"].shape[1]
    line = ('{"type":0,"pose":{"position":{"x":0.0,"y":0.0,"z":0.0},"orientation":' + _QID + '},'
            '"thickness":%s,"scale_invariant":false,"points":[' + _POINTS_FMT + '],"color":%s,'
            '"colors":[],"indices":[]}')
    text = ('{"pose":{"position":{"x":%.3f,"y":%.3f,"z":3.0},"orientation":' + _QID + '},"billboard":true,'
            '"font_size":14.0,"scale_invariant":true,"color":' + _WHITE + ',"text":"episode ' + str(ep) +
            '  t=%.1fs  %s"}')
    scene_t = ('{"deletions":%s,"entities":[' + ",".join([
        _entity(ep, "road", cubes=road), _entity(ep, "vehicles", cubes=",".join(cubes)),
        _entity(ep, "rollouts", lines=",".join([line] * n_ro)), _entity(ep, "label", texts=text)]) + "]}\n")
    tf_t = ('{"timestamp":{"sec":%d,"nsec":%d},"parent_frame_id":"map","child_frame_id":"ego",'
            '"translation":{"x":%.3f,"y":%.3f,"z":0.0},"rotation":{"x":0.0,"y":0.0,"z":%.6f,"w":%.6f}}\n')

    ns = base + ks * dt_ns
    sec, nsec = (ns // 10**9).tolist(), (ns % 10**9).tolist()
    step = ks.tolist()
    x, y, psi = ego[:, 0], ego[:, 1], ego[:, 2]
    # NPC colours per step: own lane orange, oncoming red, out of the ego's sight grey and translucent.
    s = npc_s[:, present]
    reach = np.minimum(float(scen["sensor_range"][r]), scen["npc_reveal"][r][present])
    seen = np.abs(s - x[:, None]) <= reach
    npc_col = np.where(seen, np.where(lanes == 0, _ORANGE, _RED_CAR)[None, :].astype(object), _UNSEEN)
    label = [MODE_NAMES[m] for m in cap["mode"].tolist()]
    if final is not None:
        outcome, hit = final
        label[-1] = f"{label[-1]} -> {OUTCOME_NAMES[outcome].upper()}"
        if hit >= 0 and outcome == CRASH:
            npc_col[-1, present == hit] = _HIT
    qz, qw = np.sin(psi / 2).tolist(), np.cos(psi / 2).tolist()
    x, y = x.tolist(), y.tolist()
    deletions = [f'[{{"timestamp":{{"sec":{s_},"nsec":{n_}}},"type":1,"id":""}}]' if k == 0 else "[]"
                 for s_, n_, k in zip(sec, nsec, step)]
    chosen = np.arange(n_ro)[None, :] == cap["rollout"][:, None]
    color = np.array([_GREEN, _RED, _GREY_LINE], dtype=object)[np.where(chosen, 0, np.where(cap["blocked"], 1, 2))]
    thick = np.where(chosen, "0.25", "0.10")
    line_cols = []
    for ro in range(n_ro):
        pts = np.stack([cap["rollout_x"][:, ro], cap["rollout_y"][:, ro]], axis=-1).reshape(len(ks), 8)
        line_cols += [thick[:, ro].tolist(), *pts.T.tolist(), color[:, ro].tolist()]
    stamp = [sec, nsec, step]
    t = (ks * (dt_ns / 1e9)).tolist()
    npc_cols = [c for j in range(len(present)) for c in (s[:, j].tolist(), npc_col[:, j].tolist())]
    cols = [deletions, *stamp, *stamp, x, y, qz, qw, *npc_cols, *stamp, *line_cols, *stamp, x, y, t, label]
    scene_b = ((scene_t * len(ks)) % tuple(itertools.chain.from_iterable(zip(*cols)))).encode().split(b"\n")
    if final is not None:  # the final update adds an "outcome" entity (cleared by the next episode's deletion)
        scene_b[len(ks) - 1] = scene_b[len(ks) - 1][:-2] + b"," + outcome_entity(
            ep, sec[-1], nsec[-1], step[-1], x[-1], y[-1], final).encode() + b"]}"
    tf_b = ((tf_t * len(ks)) % tuple(itertools.chain.from_iterable(zip(sec, nsec, x, y, qz, qw)))
            ).encode().split(b"\n")
    out = []
    for tm, sb, tb in zip(ns.tolist(), scene_b, tf_b):
        out += [(sc_ch, tm, sb), (tf_ch, tm, tb)]
    return out

def outcome_entity(ep: int, sec: int, nsec: int, step: int, x: float, y: float, final: tuple[int, int]) -> str:
    outcome, hit = final
    words = OUTCOME_NAMES[outcome].upper() + (f" with NPC{hit + 1}" if outcome == CRASH and hit >= 0 else "")
    colour = _HIT if outcome == CRASH else (_GREEN if OUTCOME_NAMES[outcome] == "success" else _ORANGE)
    text = ('{"pose":{"position":{"x":%.3f,"y":%.3f,"z":5.0},"orientation":' % (x, y) + _QID + '},'
            '"billboard":true,"font_size":28.0,"scale_invariant":true,"color":' + colour + ',"text":"'
            + words + '"}')
    return _entity(ep, "outcome", texts=text) % (sec, nsec, step)


def _entity(ep: int, eid: str, cubes: str = "", lines: str = "", texts: str = "") -> str:
    """A foxglove.SceneEntity template: every field present; timestamp and step left as %d."""
    return ('{"timestamp":{"sec":%d,"nsec":%d},"frame_id":"map","id":"' + eid + '","lifetime":{"sec":0,"nsec":0},'
            '"frame_locked":false,"metadata":[{"key":"episode","value":"' + str(ep) + '"},{"key":"step","value":"%d"}],'
            '"arrows":[],"cubes":[' + cubes + '],"spheres":[],"cylinders":[],"lines":[' + lines + '],'
            '"triangles":[],"texts":[' + texts + '],"models":[]}')


# Scene JSON templates (Foxglove fields in full; display precision only, the state topics are exact).
_POINTS_FMT = ",".join(['{"x":%.3f,"y":%.3f,"z":0.05}'] * 4)
_QID = '{"x":0.0,"y":0.0,"z":0.0,"w":1.0}'
_CUBE_FMT = ('{"pose":{"position":{"x":%.3f,"y":%.3f,"z":%.3f},"orientation":{"x":0.0,"y":0.0,"z":%.6f,"w":%.6f}},'
             '"size":{"x":%.3f,"y":%.3f,"z":%.3f},"color":%s}')
_rgba = lambda r, g, b, a: '{"r":%g,"g":%g,"b":%g,"a":%g}' % (r, g, b, a)  # noqa: E731
_ROAD, _ROAD_OPP, _WHITE, _GOAL = _rgba(.25, .25, .25, 1), _rgba(.3, .3, .3, 1), _rgba(1, 1, 1, 1), _rgba(.1, .8, .1, 1)
_BLUE, _ORANGE, _RED_CAR = _rgba(.1, .4, 1, 1), _rgba(1, .6, .1, 1), _rgba(.9, .1, .1, 1)
_GREEN, _RED, _GREY_LINE = _rgba(.1, .9, .1, 1), _rgba(.9, .2, .2, .6), _rgba(.8, .8, .8, .5)
_UNSEEN, _HIT = _rgba(.6, .6, .6, .3), _rgba(1, 0, 1, 1)  # beyond the sensor / not yet revealed; the vehicle hit
