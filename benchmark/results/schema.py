"""The results file's fields (the per-scenario arrays: dtype and what a JSON null stands for) and the
validation of a results document against its JSON Schema: the first problem as one line naming the
key, and the per-scenario arrays checked item by item. The schema is :func:`results_schema`: the
hand-written ``schemas/results.schema.json`` with the arrays (registry.py) and the summary rows
(metrics.py) added, so a metric is declared in one place."""

from __future__ import annotations

import copy
import functools
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np

from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.results import registry
from overtakezoo.benchmark.results.metrics import PAIRED, SAFETY_TABLE, TABLE

# Per-scenario arrays: name -> (dtype, value a JSON null stands for), views of registry.py's declarations.
PER_SCENARIO: Mapping[str, tuple[type, float | None]] = registry.ArraysView(registry.CORE)
# ... and in multi-AV files: the other AV a crash was with (its index, -1 none), the AV's own lead's NPC slot.
MULTI_PER_SCENARIO: Mapping[str, tuple[type, float | None]] = registry.ArraysView(registry.MULTI)
# The safety metrics (issue 22; docs/metrics.md): a file has all of them or none (files written before
# they existed, e.g. the shipped leaderboard rows, have none and still load; verify compares what a row has).
# -1 in the int arrays: not applicable (no merge back / never unsafe).
SAFETY_PER_SCENARIO: Mapping[str, tuple[type, float | None]] = registry.ArraysView(registry.SAFETY)


def per_scenario_keys(num_avs: int = 1) -> Mapping[str, tuple[type, float | None]]:
    """The per-scenario arrays of a results file with ``num_avs`` AVs per scenario."""
    return PER_SCENARIO if num_avs == 1 else {**PER_SCENARIO, **MULTI_PER_SCENARIO}


def recorded_keys(num_avs: int = 1, safety: bool = True) -> dict[str, tuple[type, float | None]]:
    """The per-scenario arrays a run records (``run/runner.py``; ``safety`` off: ``eval --no-safety``).
    With ``safety`` on: what every leaderboard row must hold, one value per scenario and AV
    (``leaderboard/rows.py``: ``suite_mismatch``). The one list of them: both read it here."""
    return {**per_scenario_keys(num_avs), **(SAFETY_PER_SCENARIO if safety else {})}


def stored_keys(per: Mapping[str, Any], num_avs: int = 1) -> Mapping[str, tuple[type, float | None]]:
    """The per-scenario arrays ``per`` holds: the required ones, and the safety ones when it has them."""
    keys = per_scenario_keys(num_avs)
    return {**keys, **SAFETY_PER_SCENARIO} if any(k in per for k in SAFETY_PER_SCENARIO) else keys


SCHEMA_ID = "overtakezoo-results/1"


SCHEMA_PATH = Path(__file__).with_name("schemas") / "results.schema.json"  # all but the arrays and summary rows
_STAT = {  # a summary row: value with its 95 % interval, n values (k of n for a rate)
    "type": "object",
    "required": ["value", "lo", "hi", "n"],
    "additionalProperties": False,
    "properties": {
        **{k: {"type": ["number", "null"]} for k in ("value", "lo", "hi")},
        **{k: {"type": "integer", "minimum": 0} for k in ("n", "k")},
    },
}


def results_schema() -> dict[str, Any]:
    """The results JSON Schema: ``SCHEMA_PATH`` with every declared array (required: the core ones)
    and every summary row (required: Table I's) added."""
    return copy.deepcopy(_schema_for(tuple(registry.METRICS)))


@functools.cache  # keyed by the declarations, so a metric added at run time gets a schema of its own
def _schema_for(metrics: tuple[registry.Metric, ...]) -> dict[str, Any]:
    schema = json.loads(SCHEMA_PATH.read_text())
    scen, summary = schema["properties"]["scenarios"], schema["properties"]["summary"]
    scen["required"] = sorted(m.name for m in metrics if m.group == registry.CORE)
    scen["properties"] = {
        m.name: {"description": f"{m.group}: {m.doc}", "type": "array", "items": m.items_schema()} for m in metrics
    }
    core_rows = [key for key, *_ in TABLE if key not in PAIRED]
    other_rows = [key for key, *_ in SAFETY_TABLE] + [m.summary_key for m in metrics if m.summary]
    summary["required"] = core_rows
    summary["properties"] = {**{k: _STAT for k in core_rows + other_rows}, **summary["properties"]}
    return schema


def _validator() -> jsonschema.protocols.Validator:
    return _validator_for(tuple(registry.METRICS))


@functools.cache
def _validator_for(metrics: tuple[registry.Metric, ...]) -> jsonschema.protocols.Validator:
    schema = _schema_for(metrics)
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
