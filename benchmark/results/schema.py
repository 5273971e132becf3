"""The results file's fields (the per-scenario arrays: dtype and what a JSON null stands for) and the
validation of a results document against ``schemas/results.schema.json`` (JSON Schema): the first
problem as one line naming the key, and the per-scenario arrays checked item by item."""

from __future__ import annotations

import functools
import json
import math
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np

from overtakezoo.benchmark.errors import UserError

# Per-scenario arrays: name -> (dtype, value a JSON null stands for).
PER_SCENARIO: dict[str, tuple[type, float | None]] = {
    "outcome": (np.int8, None),
    "crash_npc": (np.int64, None),
    "crash_lane": (np.int64, None),
    "completion_time": (np.float64, math.nan),
    "episode_time": (np.float64, math.nan),
    "aborts": (np.int64, None),
    "switches": (np.int64, None),
    "opposite_time": (np.float64, math.nan),
    "min_ttc": (np.float64, math.inf),  # inf: never on a collision course
    "peak_lat_accel": (np.float64, math.nan),
    "peak_jerk": (np.float64, math.nan),
    "npc1_speed": (np.float64, math.nan),
    "npc2_speed": (np.float64, math.nan),
}


# ... and in multi-AV files: the other AV a crash was with (its index, -1 none), the AV's own lead's NPC slot.
MULTI_PER_SCENARIO: dict[str, tuple[type, float | None]] = {"crash_av": (np.int64, None), "lead_npc": (np.int64, None)}


# The safety metrics (issue 22; docs/metrics.md): a file has all of them or none (files written before
# they existed, e.g. the shipped leaderboard rows, have none and still load; verify compares what a row has).
# -1 in the int arrays: not applicable (no merge back / never unsafe).
SAFETY_PER_SCENARIO: dict[str, tuple[type, float | None]] = {
    "rss_violation_share": (np.float64, math.nan),
    "rss_first_violation": (np.float64, math.nan),
    "rss_worst_margin": (np.float64, math.nan),
    "rss_merge_violation": (np.int8, None),
    "min_headon_ttc": (np.float64, math.inf),  # inf: never closing head-on in the opposite lane
    "cutin_pet": (np.float64, math.nan),
    "abort_delay": (np.float64, math.nan),
    "late_abort": (np.int8, None),
    "ponr_margin": (np.float64, math.nan),
}


def per_scenario_keys(num_avs: int = 1) -> dict[str, tuple[type, float | None]]:
    """The per-scenario arrays of a results file with ``num_avs`` AVs per scenario."""
    return PER_SCENARIO if num_avs == 1 else {**PER_SCENARIO, **MULTI_PER_SCENARIO}


def recorded_keys(num_avs: int = 1, safety: bool = True) -> dict[str, tuple[type, float | None]]:
    """The per-scenario arrays a run records (``run/runner.py``; ``safety`` off: ``eval --no-safety``).
    With ``safety`` on: what every leaderboard row must hold, one value per scenario and AV
    (``leaderboard/rows.py``: ``suite_mismatch``). The one list of them: both read it here."""
    return {**per_scenario_keys(num_avs), **(SAFETY_PER_SCENARIO if safety else {})}


def stored_keys(per: dict[str, Any], num_avs: int = 1) -> dict[str, tuple[type, float | None]]:
    """The per-scenario arrays ``per`` holds: the required ones, and the safety ones when it has them."""
    keys = per_scenario_keys(num_avs)
    return {**keys, **SAFETY_PER_SCENARIO} if any(k in per for k in SAFETY_PER_SCENARIO) else keys


SCHEMA_ID = "overtakezoo-results/1"


SCHEMA_PATH = Path(__file__).with_name("schemas") / "results.schema.json"


@functools.cache
def _validator() -> jsonschema.protocols.Validator:
    schema = json.loads(SCHEMA_PATH.read_text())
    cls = jsonschema.validators.validator_for(schema)
    cls.check_schema(schema)
    # JSON Schema counts 0.0 as an integer; numpy seeds, counts and indices need a real int.
    strict = cls.TYPE_CHECKER.redefine("integer", lambda _, v: isinstance(v, int) and not isinstance(v, bool))
    return jsonschema.validators.extend(cls, type_checker=strict)(schema)


def validate(doc: Any, where: str = "results") -> None:
    """Raise a UserError naming the first field that does not match the schema.

    The per-scenario arrays (tens of thousands of numbers) are checked against their ``items``
    schema with numpy; jsonschema checks everything else (the arrays' shape included)."""
    scen = doc.get("scenarios") if isinstance(doc, dict) else None
    arrays = {}
    if isinstance(scen, dict):
        known = {**per_scenario_keys(2), **SAFETY_PER_SCENARIO}
        arrays = {k: v for k, v in scen.items() if isinstance(v, list) and k in known}
        doc = {**doc, "scenarios": {**scen, **{k: [] for k in arrays}}}
    error = next(iter(_validator().iter_errors(doc)), None)  # the first error: its path is the field to fix
    if error is not None:
        path = ".".join(str(p) for p in error.absolute_path) or "(top level)"
        message = error.message if len(error.message) < 200 else error.message[:200] + "..."
        raise UserError(f"{where}: {path}: {message}")
    items = _validator().schema["properties"]["scenarios"]["properties"]
    for key, values in arrays.items():
        bad = _first_bad_item(values, items[key]["items"])
        if bad is not None:
            raise UserError(f"{where}: scenarios.{key}.{bad[0]}: {bad[1]}")


def _first_bad_item(values: list[Any], spec: dict[str, Any]) -> tuple[int, str] | None:
    """(index, reason) of the first value breaking ``spec`` (type / minimum / maximum), or None."""
    types = spec["type"] if isinstance(spec["type"], list) else [spec["type"]]
    allowed = (int,) if types == ["integer"] else (int, float, type(None))
    for i, v in enumerate(values):
        if type(v) not in allowed:  # bool is not an int here, as in JSON Schema
            return i, f"{v!r} is not of type {', '.join(repr(t) for t in types)}"
    try:
        a = np.array([np.nan if v is None else v for v in values], dtype=np.float64)
    except OverflowError:
        return next(i for i, v in enumerate(values) if isinstance(v, int) and abs(v) > 1e300), "too large"
    with np.errstate(invalid="ignore"):
        out = np.flatnonzero((a < spec["minimum"]) | (a > spec["maximum"]))
    if out.size:
        i = int(out[0])
        return i, f"{values[i]!r} is outside [{spec['minimum']}, {spec['maximum']}]"
    return None
