"""Results files: provenance, per-scenario arrays and a summary with CIs, as one JSON document.

Everything but the ``timing`` field is a function of (suite file, decider, code), so running the
same command twice gives byte-identical files apart from ``timing``. A multi-AV suite's file has
``num_avs`` (E >= 2) and stores each per-scenario array once per AV, AV-major (AV e's value for
scenario i at ``e * n + i``), with two more arrays (MULTI_PER_SCENARIO); its summary adds the
per-AV and joint outcomes (multi_metrics.py). Single-ego files have neither. Loading validates against
the results schema (schema.py; the arrays as registry.py declares them) and recomputes the summary
from the arrays; any mismatch is a UserError naming the field.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import subprocess
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.results.metrics import summarize
from overtakezoo.benchmark.results.schema import (
    PER_SCENARIO,
    SAFETY_PER_SCENARIO,
    SCHEMA_ID,
    per_scenario_keys,
    stored_keys,
    validate,
)
from overtakezoo.envs import SIM_VERSION, safe_json
from overtakezoo.envs.io import atomic_write_text

_OPTIONAL = ("sim_version", "submission", "num_avs")  # absent from older files / until submitted / single-ego


DECIMALS = 4  # per-scenario floats: 0.1 mm / 0.1 ms resolution, and compact files


def summary_of(per: dict[str, np.ndarray], seed: int, num_avs: int = 1) -> dict[str, Any]:
    if num_avs == 1:
        return summarize(per, seed)
    from overtakezoo.benchmark.results.multi_metrics import summarize_multi

    return summarize_multi(per, seed, num_avs)


def round_per_scenario(per: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Cast and round once, so summaries are computed from exactly what the file stores."""
    out = {}
    for key, (dtype, _) in stored_keys(per, 2 if "crash_av" in per else 1).items():
        a = np.asarray(per[key])
        out[key] = np.round(a.astype(np.float64), DECIMALS) if dtype is np.float64 else a.astype(dtype)
    return out


@functools.cache
def package_version() -> str:
    try:
        return metadata.version("overtakezoo")
    except metadata.PackageNotFoundError:
        return "unknown"


@functools.cache
def git_commit() -> str | None:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=Path(__file__).parent,
            capture_output=True,
            text=True,
            timeout=5,
            check=True,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    commit = out.stdout.strip()
    return commit if len(commit) == 40 else None


# (table, key) -> the value under which the setting changes nothing that was measured before it existed.
ADDED_LATER = {
    ("planner", "emergency_braking"): False,
    ("observation", "v2v"): False,
    ("observation", "time_left"): False,
}


def config_sha256(config: Any) -> str:
    """Hash of the resolved settings: catches a change of library defaults the suite file does not name.
    The reward is left out: it changes no outcome or statistic a results file records. A setting added
    after rows were recorded is left out while it holds the value that reproduces them (ADDED_LATER)."""
    settings = {k: v for k, v in config.to_dict().items() if k != "reward"}
    for (table, key), neutral in ADDED_LATER.items():
        if settings[table].get(key) == neutral:
            del settings[table][key]
    text = json.dumps(settings, sort_keys=True, default=repr)
    return hashlib.sha256(text.encode()).hexdigest()


@dataclass
class Results:
    meta: dict[str, Any]  # suite, decider, package, git_commit, seed, sim_version, shard, range, config_sha256,
    #                       submission (the leaderboard row: name and policy; None until submitted)
    per: dict[str, np.ndarray]
    summary: dict[str, Any]
    timing: dict[str, Any] = field(default_factory=dict)

    # ------------------------------------------------------------ building
    @classmethod
    def create(
        cls,
        suite: Any,
        decider: Any,
        per: dict[str, np.ndarray],
        *,
        start: int,
        stop: int,
        shard: tuple[int, int] | None,
        timing: dict[str, Any],
        num_avs: int = 1,
    ) -> Results:
        meta = {
            "suite": {"name": suite.name, "version": suite.version, "hash": suite.hash, "count": suite.count},
            "config_sha256": config_sha256(suite.config),
            "decider": {
                "name": str(decider.name),
                "version": str(decider.version),
                "weights_sha256": getattr(decider, "weights_sha256", None),
                "privileged": bool(getattr(decider, "privileged", False)),
                # What a --policy was (kind, file, sha256); zoo members by name have none.
                **({"policy": decider.policy} if getattr(decider, "policy", None) else {}),
            },
            "package": {"name": "overtakezoo", "version": package_version()},
            "git_commit": git_commit(),
            "seed": suite.seed,
            "sim_version": SIM_VERSION,
            "shard": list(shard) if shard is not None else None,
            "range": [start, stop],
            "submission": None,
            "num_avs": num_avs if num_avs > 1 else None,
        }
        per = round_per_scenario(per)
        return cls(meta, per, summary_of(per, suite.seed, num_avs), timing)

    @property
    def suite(self) -> dict[str, Any]:
        return self.meta["suite"]

    @property
    def decider(self) -> dict[str, Any]:
        return self.meta["decider"]

    @property
    def num_avs(self) -> int:
        return int(self.meta.get("num_avs") or 1)

    @property
    def complete(self) -> bool:
        return self.meta["range"] == [0, self.suite["count"]]

    def per_scenario_array(self, key: str) -> np.ndarray:
        """One per-scenario array (``outcome``, ``completion_time``, ... see PER_SCENARIO)."""
        return self.per[key]

    def __getattr__(self, key: str) -> np.ndarray:
        # ``results.outcome`` etc. as shorthands for the per-scenario arrays.
        per = self.__dict__.get("per")
        if per is not None and key in per:
            return per[key]
        raise AttributeError(key)

    # ------------------------------------------------------------ JSON
    def to_dict(self) -> dict[str, Any]:
        meta = {k: v for k, v in self.meta.items() if v is not None or k not in _OPTIONAL}
        return {
            "schema": SCHEMA_ID,
            **meta,
            "scenarios": {k: _to_list(v) for k, v in self.per.items()},
            "summary": self.summary,
            "timing": self.timing,
        }

    def to_json(self) -> str:
        """Indented JSON with each per-scenario array on one line (compact, still diffable)."""
        doc = self.to_dict()
        arrays = doc.pop("scenarios")
        doc["scenarios"] = {k: f"@@{k}@@" for k in arrays}
        text = json.dumps(doc, indent=1, sort_keys=True, allow_nan=False)
        for k, values in arrays.items():
            text = text.replace(f'"@@{k}@@"', json.dumps(values, separators=(",", ":"), allow_nan=False))
        return text + "\n"

    def without_timing(self) -> str:
        return Results(self.meta, self.per, self.summary, {}).to_json()

    def save(self, path: str | Path) -> Path:
        validate(self.to_dict(), str(path))  # never write a file that would not load
        return atomic_write_text(path, self.to_json())

    @classmethod
    def load(cls, path: str | Path) -> Results:
        path = Path(path)
        try:
            data = safe_json.read_bounded(path)
        except OSError as exc:
            raise UserError(f"cannot read results file {path}: {exc.strerror or exc}") from None
        return cls.from_json(data, str(path))

    @classmethod
    def from_json(cls, data: bytes | str, where: str = "results") -> Results:
        try:
            doc = safe_json.loads(data, where, parse_constant=_reject_constant)  # bounded size and depth
        except safe_json.JSONInputError as exc:
            raise UserError(f"{where}: not a valid JSON document: {exc.reason}") from None
        except (ValueError, RecursionError) as exc:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
            raise UserError(f"{where}: not a valid JSON document: {str(exc).splitlines()[0][:200]}") from None
        validate(doc, where)
        meta = {
            k: doc[k] for k in ("suite", "config_sha256", "decider", "package", "git_commit", "seed", "shard", "range")
        }
        meta.update({k: doc.get(k) for k in _OPTIONAL})
        start, stop = meta["range"]
        if not 0 <= start < stop <= meta["suite"]["count"]:
            raise UserError(f"{where}: range: {meta['range']} is not inside [0, {meta['suite']['count']}]")
        shard = meta["shard"]
        if shard is not None:
            from overtakezoo.envs.suites import shard_bounds

            if not 0 <= shard[0] < shard[1] <= meta["suite"]["count"] or list(
                shard_bounds(meta["suite"]["count"], tuple(shard))
            ) != [start, stop]:
                raise UserError(f"{where}: shard: {shard} does not match range {meta['range']}")
        per = {}
        num_avs = int(meta.get("num_avs") or 1)
        for key, (dtype, null) in stored_keys(doc["scenarios"], num_avs).items():
            values = doc["scenarios"].get(key)
            if values is None:
                why = (
                    "a file with any safety array needs all"
                    if key in SAFETY_PER_SCENARIO
                    else f"a file with num_avs {num_avs} needs it"
                )
                raise UserError(f"{where}: scenarios.{key}: missing ({why})")
            if len(values) != (stop - start) * num_avs:
                raise UserError(
                    f"{where}: scenarios.{key}: expected {(stop - start) * num_avs} values "
                    f"({num_avs} per scenario), got {len(values)}"
                )
            if dtype is np.float64:
                per[key] = np.array([null if v is None else v for v in values], dtype=np.float64)
            else:
                per[key] = np.array(values, dtype=dtype)
        if num_avs == 1 and set(doc["scenarios"]) - set(PER_SCENARIO) - set(SAFETY_PER_SCENARIO):
            extra = sorted(set(doc["scenarios"]) - set(PER_SCENARIO) - set(SAFETY_PER_SCENARIO))[0]
            raise UserError(f"{where}: scenarios: {extra}: only in multi-AV files (num_avs >= 2)")
        per = round_per_scenario(per)
        summary = summary_of(per, meta["seed"], num_avs)
        if not same_summary(summary, doc["summary"]):
            raise UserError(f"{where}: summary: does not match the per-scenario arrays (edited by hand?)")
        return cls(meta, per, summary, doc["timing"])


def merge(parts: list[Results]) -> Results:
    """Combine shard results into the result of one full run (equal to it apart from ``timing``)."""
    if not parts:
        raise UserError("merge: no results given")
    first = parts[0]
    for p in parts[1:]:
        for key in ("suite", "config_sha256", "decider", "package", "git_commit", "seed", "sim_version", "num_avs"):
            if p.meta[key] != first.meta[key]:
                raise UserError(f"merge: {key}: shards differ ({first.meta[key]!r} vs {p.meta[key]!r})")
    parts = sorted(parts, key=lambda p: p.meta["range"][0])
    edge = 0
    for p in parts:
        start, stop = p.meta["range"]
        if start != edge:
            what = "overlap" if start < edge else "leave a gap"
            raise UserError(f"merge: range: shards {what} at scenario {min(start, edge)}")
        edge = stop
    if edge != first.suite["count"]:
        raise UserError(f"merge: range: shards cover {edge} of {first.suite['count']} scenarios")
    e = first.num_avs  # AV-major: join each AV's part of every shard
    # (the safety arrays only when every shard has them)
    keys = (
        stored_keys(first.per, e)
        if all(any(k in p.per for k in SAFETY_PER_SCENARIO) for p in parts)
        else per_scenario_keys(e)
    )
    per = {k: np.concatenate([p.per[k].reshape(e, -1) for p in parts], axis=1).reshape(-1) for k in keys}
    meta = {**first.meta, "shard": None, "range": [0, edge], "submission": None}
    timing = {
        "wall_time_s": round(sum(p.timing.get("wall_time_s", 0.0) for p in parts), 3),
        "started": min(str(p.timing.get("started", "")) for p in parts),
        "steps": sum(int(p.timing.get("steps", 0)) for p in parts),
        "shards": len(parts),
    }
    return Results(meta, per, summary_of(per, meta["seed"], e), timing)


def _to_list(a: np.ndarray) -> list[Any]:
    if a.dtype.kind == "f":
        return [v if math.isfinite(v) else None for v in a.tolist()]
    return a.tolist()


def _reject_constant(name: str) -> None:
    raise ValueError(f"{name} is not allowed (use null)")


def same_summary(a: Any, b: Any) -> bool:
    """Whether two summaries are the same document (a recorded one against :func:`summary_of`)."""
    return _canonical(a) == _canonical(b)


def _canonical(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, allow_nan=True)
