"""The OvertakeZoo MCAP archive format: topics, constants and the schemas registered per channel
(the layout is described in :mod:`overtakezoo.benchmark.archive.recorder`): JSON with JSON Schemas
for the per-episode topics, CDR with ROS 2 message definitions (``ros2msg``) for the per-step ones,
Foxglove's own ``foxglove_msgs`` definitions for the scene (Foxglove decodes both natively)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from overtakezoo.benchmark.results import registry

EPISODE_GAP_NS = 1 * 10**9  # episodes follow each other on the timeline with this gap (the last scene stays up)
FORMAT_VERSION = "3"  # 3: per-step topics in CDR (ros2msg schemas); 2 (JSON throughout) is not read
STATE_TOPICS = ("/episode/spec", "/state", "/episode/summary")  # what the reader needs
# /episode/summary: the core's info() at the episode's end. These first, in format 3's order, then the
# results arrays the core reports (results/registry.py: source INFO; archives are single-ego).
_EPISODE_FIELDS = ("outcome", "crash_npc", "crash_lane", "t", "episode_return", "episode_steps")
_RESULTS_FIELDS = [m for m in registry.recorded(1, safety=False) if m.source == registry.INFO]
SUMMARY_FIELDS = (*_EPISODE_FIELDS, *(m.source_key for m in _RESULTS_FIELDS if m.source_key not in _EPISODE_FIELDS))
# null means +inf for these (a scenario's never-revealed NPC, the arrays declared so), NaN for every other field
INF_FIELDS = {"npc_reveal", *(m.source_key for m in _RESULTS_FIELDS if m.null == math.inf)}


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
    "/episode/spec": (
        "overtakezoo.EpisodeSpec",
        _obj(
            {
                **_HEAD,
                **_T,
                "scenario": {
                    "type": "object",
                    "description": "one row of overtakezoo.envs.Scenarios: scalars and per-NPC arrays",
                    "additionalProperties": {"type": ["number", "boolean", "null", "array"]},
                },
            }
        ),
    ),
    "/episode/index": (
        "overtakezoo.EpisodeIndex",
        _obj({**_HEAD, "start_ns": _INT, "end_ns": _INT, "steps": _INT, "outcome_name": _STR}),
    ),
    "/episode/summary": (
        "overtakezoo.EpisodeSummary",
        _obj(
            {
                **_HEAD,
                **_T,
                "outcome_name": _STR,
                "start_ns": _INT,
                "end_ns": _INT,
                **{k: _NUM_NULL for k in SUMMARY_FIELDS},
            }
        ),
    ),
}

# ---------------------------------------------------------------------------- ROS 2 message definitions
# Per-step topics are CDR-encoded with these definitions (MCAP schema encoding "ros2msg": the main
# definition, then each dependency after a line of 80 "=" and "MSG: pkg/Name"). The foxglove_msgs
# ones are Foxglove's (github.com/foxglove/schemas, ros_foxglove_msgs/ros2), comments dropped.
STATE_MSG = """uint32 episode
uint32 step
float64 t
float64 x
float64 y
float64 psi
float64 v
float64 a
float64 steer
float64 reward
uint8 mode
uint8 rollout
float64[] npc_s
float64[] npc_v
float64[] offsets
bool[] blocked
"""
_DEFS = {
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    "geometry_msgs/Pose": "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n",
    "foxglove_msgs/Color": "float64 r\nfloat64 g\nfloat64 b\nfloat64 a\n",
    "foxglove_msgs/KeyValuePair": "string key\nstring value\n",
    "foxglove_msgs/FrameTransform": (
        "builtin_interfaces/Time timestamp\nstring parent_frame_id\nstring child_frame_id\n"
        "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n"
    ),
    "foxglove_msgs/SceneEntityDeletion": (
        "builtin_interfaces/Time timestamp\nuint8 MATCHING_ID=0\nuint8 ALL=1\nuint8 type\nstring id\n"
    ),
    "foxglove_msgs/ArrowPrimitive": (
        "geometry_msgs/Pose pose\nfloat64 shaft_length\nfloat64 shaft_diameter\n"
        "float64 head_length\nfloat64 head_diameter\nfoxglove_msgs/Color color\n"
    ),
    "foxglove_msgs/CubePrimitive": "geometry_msgs/Pose pose\ngeometry_msgs/Vector3 size\nfoxglove_msgs/Color color\n",
    "foxglove_msgs/SpherePrimitive": "geometry_msgs/Pose pose\ngeometry_msgs/Vector3 size\nfoxglove_msgs/Color color\n",
    "foxglove_msgs/CylinderPrimitive": (
        "geometry_msgs/Pose pose\ngeometry_msgs/Vector3 size\nfloat64 bottom_scale\n"
        "float64 top_scale\nfoxglove_msgs/Color color\n"
    ),
    "foxglove_msgs/LinePrimitive": (
        "uint8 LINE_STRIP=0\nuint8 LINE_LOOP=1\nuint8 LINE_LIST=2\nuint8 type\n"
        "geometry_msgs/Pose pose\nfloat64 thickness\nbool scale_invariant\n"
        "geometry_msgs/Point[] points\nfoxglove_msgs/Color color\nfoxglove_msgs/Color[] colors\n"
        "uint32[] indices\n"
    ),
    "foxglove_msgs/TriangleListPrimitive": (
        "geometry_msgs/Pose pose\ngeometry_msgs/Point[] points\n"
        "foxglove_msgs/Color color\nfoxglove_msgs/Color[] colors\nuint32[] indices\n"
    ),
    "foxglove_msgs/TextPrimitive": (
        "geometry_msgs/Pose pose\nbool billboard\nfloat64 font_size\nbool scale_invariant\n"
        "foxglove_msgs/Color color\nstring text\n"
    ),
    "foxglove_msgs/ModelPrimitive": (
        "geometry_msgs/Pose pose\ngeometry_msgs/Vector3 scale\nfoxglove_msgs/Color color\n"
        "bool override_color\nstring url\nstring media_type\nuint8[] data\n"
    ),
    "foxglove_msgs/SceneEntity": (
        "builtin_interfaces/Time timestamp\nstring frame_id\nstring id\n"
        "builtin_interfaces/Duration lifetime\nbool frame_locked\n"
        "foxglove_msgs/KeyValuePair[] metadata\nfoxglove_msgs/ArrowPrimitive[] arrows\n"
        "foxglove_msgs/CubePrimitive[] cubes\nfoxglove_msgs/SpherePrimitive[] spheres\n"
        "foxglove_msgs/CylinderPrimitive[] cylinders\nfoxglove_msgs/LinePrimitive[] lines\n"
        "foxglove_msgs/TriangleListPrimitive[] triangles\nfoxglove_msgs/TextPrimitive[] texts\n"
        "foxglove_msgs/ModelPrimitive[] models\n"
    ),
}
_SEP = "=" * 80 + "\n"


def _msgdef(main: str, deps: list[str]) -> str:
    return main + "".join(f"{_SEP}MSG: {d}\n{_DEFS[d]}" for d in deps)


_GEOM = ["geometry_msgs/Pose", "geometry_msgs/Point", "geometry_msgs/Quaternion", "geometry_msgs/Vector3"]
SCENE_MSG = _msgdef(
    "foxglove_msgs/SceneEntityDeletion[] deletions\nfoxglove_msgs/SceneEntity[] entities\n",
    [
        "foxglove_msgs/SceneEntityDeletion",
        "foxglove_msgs/SceneEntity",
        "foxglove_msgs/KeyValuePair",
        "foxglove_msgs/ArrowPrimitive",
        "foxglove_msgs/CubePrimitive",
        "foxglove_msgs/SpherePrimitive",
        "foxglove_msgs/CylinderPrimitive",
        "foxglove_msgs/LinePrimitive",
        "foxglove_msgs/TriangleListPrimitive",
        "foxglove_msgs/TextPrimitive",
        "foxglove_msgs/ModelPrimitive",
        *_GEOM,
        "foxglove_msgs/Color",
    ],
)
TF_MSG = _msgdef(
    "foxglove_msgs/FrameTransform[] transforms\n",
    ["foxglove_msgs/FrameTransform", "geometry_msgs/Vector3", "geometry_msgs/Quaternion"],
)

# topic -> (schema name, ros2msg definition). The scene is split by what changes when: the road
# (once per episode), the vehicles (their colours change when the sensor sees them), the rollouts,
# the label and the outcome; /tf moves the vehicle frames at every scene step.
SCENE_TOPICS = ("/scene/road", "/scene/vehicles", "/scene/rollouts", "/scene/label", "/scene/outcome")
ROS2_SCHEMAS: dict[str, tuple[str, str]] = {
    "/state": ("overtakezoo_msgs/msg/State", STATE_MSG),
    "/tf": ("foxglove_msgs/msg/FrameTransforms", TF_MSG),
    **{t: ("foxglove_msgs/msg/SceneUpdate", SCENE_MSG) for t in SCENE_TOPICS},
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
