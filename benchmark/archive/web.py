"""One archived episode as a small self-contained JSON file for the browser viewer (``docs/viewer/``).

``overtakezoo replay RUN.mcap --episode K --out ep.json`` writes it. The file holds what the top view
draws (:mod:`overtakezoo.envs.faces.render`), nothing it does not: the scenario's constants once, then
one value per step for the ego and per NPC slot and step, rounded (positions to the millimetre,
headings to 1e-4 rad, speeds to the mm/s), and the planner's rollouts as stored in the archive (each
rollout's end offset, which ones were blocked, which one was chosen). Non-finite numbers (an NPC
revealed from the start: ``npc_reveal`` = inf; a missing time-to-collision) are written as ``null``,
which JSON has and the viewer reads as "none" / infinity.

Layout (``version`` 1), every per-step array of length ``steps + 1`` (index 0: after reset)::

    format, version, episode, source {suite, suite_version, suite_hash, decider, decider_version},
    dt, steps, mode_names, outcome_names, outcome, crash_npc, summary {...},
    scenario {lane_width, goal_s, road_length, sensor_range, time_limit, speed_limit, ego_length,
              ego_width, npc_present, npc_lane, npc_length, npc_width, npc_reveal},
    planner {roll_in_speed_factor, roll_in_margin, car_tip_margin, horizon_time},
    track {t, ego_x, ego_y, ego_psi, ego_v, mode, npc_s [slot][step], npc_v [slot][step],
           rollout (-1 at step 0: no plan yet), blocked ("01..." per rollout; "" at step 0),
           offsets ([R] when the same at every step, else [step][R] with null at step 0)}

``mode[k]`` is the mode applied during the step that led to step ``k`` (as the GIF replay draws it).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from overtakezoo.benchmark.archive.reader import Episode, read_archive_meta, read_episode
from overtakezoo.benchmark.archive.replay import _planner
from overtakezoo.benchmark.errors import UserError
from overtakezoo.envs import MODE_NAMES, OUTCOME_NAMES
from overtakezoo.envs.io import atomic_write_text

FORMAT = "overtakezoo-episode"
VERSION = 1
SCENARIO_KEYS = (
    "lane_width",
    "goal_s",
    "road_length",
    "sensor_range",
    "time_limit",
    "speed_limit",
    "ego_length",
    "ego_width",
)
NPC_KEYS = ("npc_present", "npc_lane", "npc_length", "npc_width", "npc_reveal")
SUMMARY_KEYS = (
    "episode_return",
    "completion_time",
    "aborts",
    "switches",
    "opposite_time",
    "min_ttc",
    "peak_lat_accel",
    "peak_jerk",
    "crash_lane",
)
SOURCE_KEYS = ("suite", "suite_version", "suite_hash", "decider", "decider_version")


def _num(x: Any, digits: int = 4) -> Any:
    """A JSON number: ints kept, floats rounded, non-finite as None."""
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    x = float(x)
    return round(x, digits) if math.isfinite(x) else None


def _arr(a: Any, digits: int) -> list[Any]:
    """A float array, rounded, as a (nested) list; non-finite entries as None."""
    a = np.asarray(a, dtype=float)
    out = np.round(a, digits).tolist()
    if np.isfinite(a).all():
        return out
    mask = np.isfinite(a).tolist()

    def fix(v: Any, ok: Any) -> Any:
        return [fix(x, o) for x, o in zip(v, ok, strict=True)] if isinstance(v, list) else (v if ok else None)

    return fix(out, mask)


def episode_document(ep: Episode, meta: dict[str, str]) -> dict[str, Any]:
    """The viewer's JSON document for episode ``ep`` of an archive with run metadata ``meta``."""
    sc = ep.scenario
    steps = len(ep.t) - 1
    blocked = [""] + ["".join("1" if b else "0" for b in row) for row in np.asarray(ep.blocked, bool)]
    offsets = np.asarray(ep.offsets, dtype=float)
    same = len(offsets) == 0 or bool((offsets == offsets[:1]).all())
    return {
        "format": FORMAT,
        "version": VERSION,
        "episode": int(ep.index),
        "source": {k: meta[k] for k in SOURCE_KEYS if k in meta},
        "dt": _num(int(meta.get("dt_ns", "100000000")) / 1e9, 6),
        "steps": steps,
        "mode_names": list(MODE_NAMES),
        "outcome_names": list(OUTCOME_NAMES),
        "outcome": ep.outcome,
        "crash_npc": int(ep.summary.get("crash_npc", -1)),
        "summary": {k: _num(ep.summary[k]) for k in SUMMARY_KEYS if k in ep.summary},
        "scenario": {**{k: _num(sc[k]) for k in SCENARIO_KEYS}, **{k: [_num(v) for v in sc[k]] for k in NPC_KEYS}},
        "planner": {k: _num(v, 6) for k, v in _planner(meta).items()},
        "track": {
            "t": _arr(ep.t, 3),
            "ego_x": _arr(ep.ego["x"], 3),
            "ego_y": _arr(ep.ego["y"], 3),
            "ego_psi": _arr(ep.ego["psi"], 4),
            "ego_v": _arr(ep.ego["v"], 3),
            "mode": [0] + np.asarray(ep.mode, dtype=int).tolist(),
            "npc_s": _arr(np.asarray(ep.npc_s).T, 3),
            "npc_v": _arr(np.asarray(ep.npc_v).T, 3),
            "rollout": [-1] + np.asarray(ep.rollout, dtype=int).tolist(),
            "blocked": blocked,
            "offsets": _arr(offsets[0], 3) if same and len(offsets) else [None, *_arr(offsets, 3)],
        },
    }


def export_episode(path: str | Path, episode: int, out: str | Path) -> Path:
    """Write episode ``episode`` of archive ``path`` to ``out`` as the viewer's JSON (atomically:
    the archive is read whole before the file is made, and a failure leaves no partial file)."""
    out = Path(out)
    ep = read_episode(path, episode)  # UserError for a missing episode or a file that is no archive
    doc = episode_document(ep, read_archive_meta(path))
    text = json.dumps(doc, separators=(",", ":"), allow_nan=False) + "\n"
    try:
        atomic_write_text(out, text)
    except OSError as exc:
        raise UserError(f"cannot write {out}: {exc.strerror or exc}") from None
    return out
