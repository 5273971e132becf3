"""The OvertakeZoo MCAP archive format: topics, constants and the JSON Schemas registered per channel
(the layout is described in :mod:`overtakezoo.benchmark.archive.recorder`)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

EPISODE_GAP_NS = 1 * 10**9  # episodes follow each other on the timeline with this gap (the last scene stays up)
FORMAT_VERSION = "2"
STATE_TOPICS = ("/episode/spec", "/ego", "/npcs", "/decision", "/planner", "/reward", "/episode/summary")
SUMMARY_FIELDS = ("outcome", "crash_npc", "crash_lane", "t", "episode_return", "episode_steps", "completion_time",
                  "aborts", "switches", "opposite_time", "min_ttc", "peak_lat_accel", "peak_jerk")
INF_FIELDS = {"min_ttc", "npc_reveal"}  # null means +inf for these, NaN for every other field


# ---------------------------------------------------------------------------- schemas
def _obj(props: dict[str, Any], title: str | None = None, required: bool = True) -> dict[str, Any]:
    out: dict[str, Any] = {"type": "object", "properties": props}
    if title:
        out["title"] = title
    if required:
        out["required"] = list(props)
    return out


_NUM, _INT, _STR, _BOOL = {"type": "number"}, {"type": "integer"}, {"type": "string"}, {"type": "boolean"}
_NUM_NULL = {"type": ["number", "null"]}
_ARR = lambda item: {"type": "array", "items": item}  # noqa: E731
_HEAD = {"episode": {**_INT, "description": "global scenario index"}, "step": _INT}
_T = {"t": {**_NUM, "description": "simulated time, s (the state and summary topics carry it)"}}

SCHEMAS: dict[str, tuple[str, dict[str, Any]]] = {
    "/episode/spec": ("overtakezoo.EpisodeSpec", _obj({**_HEAD, **_T, "scenario": {
        "type": "object", "description": "one row of overtakezoo.envs.Scenarios: scalars and per-NPC arrays",
        "additionalProperties": {"type": ["number", "boolean", "null", "array"]}}})),
    "/ego": ("overtakezoo.Ego", _obj({**_HEAD, **_T, **{k: _NUM for k in ("x", "y", "psi", "v", "a", "steer")}})),
    "/npcs": ("overtakezoo.Npcs", _obj({**_HEAD, "s": _ARR(_NUM), "v": _ARR(_NUM), "lane": _ARR(_INT)})),
    "/decision": ("overtakezoo.Decision", _obj({**_HEAD, "mode": _INT, "mode_name": _STR})),
    "/planner": ("overtakezoo.Planner", _obj({**_HEAD, "offsets": _ARR(_NUM), "blocked": _ARR(_BOOL),
                                              "rollout": _INT})),
    "/reward": ("overtakezoo.Reward", _obj({**_HEAD, "reward": _NUM})),
    "/episode/index": ("overtakezoo.EpisodeIndex", _obj({
        **_HEAD, "start_ns": _INT, "end_ns": _INT, "steps": _INT, "outcome_name": _STR})),
    "/episode/summary": ("overtakezoo.EpisodeSummary", _obj({
        **_HEAD, **_T, "outcome_name": _STR, "start_ns": _INT, "end_ns": _INT,
        **{k: _NUM_NULL for k in SUMMARY_FIELDS}})),
}

# Foxglove well-known schemas, written out field by field (Foxglove keys on the schema name).
_TIME = _obj({"sec": _INT, "nsec": _INT}, "time")
_VEC3 = _obj({"x": _NUM, "y": _NUM, "z": _NUM}, "foxglove.Vector3")
_QUAT = _obj({"x": _NUM, "y": _NUM, "z": _NUM, "w": _NUM}, "foxglove.Quaternion")
_POSE = _obj({"position": _VEC3, "orientation": _QUAT}, "foxglove.Pose")
_COLOR = _obj({"r": _NUM, "g": _NUM, "b": _NUM, "a": _NUM}, "foxglove.Color")
_CUBE = _obj({"pose": _POSE, "size": _VEC3, "color": _COLOR}, "foxglove.CubePrimitive")
_LINE = _obj({"type": {"type": "integer", "description": "0 LINE_STRIP, 1 LINE_LOOP, 2 LINE_LIST"},
              "pose": _POSE, "thickness": _NUM, "scale_invariant": _BOOL, "points": _ARR(_VEC3),
              "color": _COLOR, "colors": _ARR(_COLOR), "indices": _ARR(_INT)}, "foxglove.LinePrimitive")
_TEXT = _obj({"pose": _POSE, "billboard": _BOOL, "font_size": _NUM, "scale_invariant": _BOOL,
              "color": _COLOR, "text": _STR}, "foxglove.TextPrimitive")
_ENTITY = _obj({"timestamp": _TIME, "frame_id": _STR, "id": _STR,
                "lifetime": _obj({"sec": _INT, "nsec": _INT}, "duration"), "frame_locked": _BOOL,
                "metadata": _ARR(_obj({"key": _STR, "value": _STR}, "foxglove.KeyValuePair")),
                "arrows": _ARR({"type": "object"}), "cubes": _ARR(_CUBE), "spheres": _ARR({"type": "object"}),
                "cylinders": _ARR({"type": "object"}), "lines": _ARR(_LINE),
                "triangles": _ARR({"type": "object"}), "texts": _ARR(_TEXT), "models": _ARR({"type": "object"})},
               "foxglove.SceneEntity")
FOXGLOVE_SCHEMAS = {
    "/scene": ("foxglove.SceneUpdate", _obj({
        "deletions": _ARR(_obj({"timestamp": _TIME, "type": _INT, "id": _STR}, "foxglove.SceneEntityDeletion")),
        "entities": _ARR(_ENTITY)}, "foxglove.SceneUpdate")),
    "/tf": ("foxglove.FrameTransform", _obj({"timestamp": _TIME, "parent_frame_id": _STR, "child_frame_id": _STR,
                                             "translation": _VEC3, "rotation": _QUAT}, "foxglove.FrameTransform")),
}


# ---------------------------------------------------------------------------- JSON values
def json_number(x: float) -> str:
    """A float as JSON: shortest round-trip repr, non-finite as null."""
    return repr(x) if math.isfinite(x) else "null"


def json_ready(value: Any) -> Any:
    """numpy -> JSON-ready Python, non-finite floats -> None."""
    if isinstance(value, (np.ndarray, np.generic)):
        value = value.tolist()
    if isinstance(value, list):
        return [json_ready(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
