"""Suites that list their scenarios: what ``overtakezoo search`` writes, loadable wherever a suite is.

An explicit suite is a suite file (``envs/suites.py``) with an array of ``[[scenarios]]`` tables
besides the usual keys. Its ``[scenario]`` table is a distribution as in any suite (the search box: the
road, the vehicles and the ranges), and each entry gives the values of that distribution's draws for one
scenario (``draws.draw_plan``: ``lead_speed``, ``lead_gap``, ``oncoming_speed = [...]`` one per oncoming
car, ...; optionally its own ``oncoming_count`` / ``follower_count`` / ``sensor_range``). The scenarios are
built from those values by the distribution's own sampler (``draws.build``), so each is a scenario the
distribution can draw. ``count`` is the number of entries; the ``seed`` is kept for the suite format and
draws nothing. An entry's ``[scenarios.found]`` table and the top-level ``[search]`` table record where
the scenarios came from and are not read. The hash is the file's sha256, as for every suite.

``envs/suites.py`` calls :func:`explicit_distribution` when a file has ``scenarios``; the suite's
``distribution`` is then an :class:`ExplicitDistribution`, which returns the listed scenarios.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from overtakezoo.envs.config import SuiteError
from overtakezoo.envs.draws import COUNTS, PER_ROW, Space, build, draw_plan
from overtakezoo.envs.scenarios import ScenarioDistribution, Scenarios

MAX_COUNT = 64  # the physical range of oncoming_count / follower_count (envs/scenarios.py)


class ExplicitDistribution:
    """The listed scenarios of an explicit suite, in the place of a drawn distribution.

    Every attribute but :meth:`sample` is the ``[scenario]`` table's distribution's (the road, the
    vehicle sizes, the ranges: what ``decision_map`` and the memory estimate read)."""

    def __init__(self, base: ScenarioDistribution, scenarios: Scenarios) -> None:
        self.base = base
        self.listed = scenarios

    def __getattr__(self, name: str) -> Any:
        if name in ("base", "listed"):
            raise AttributeError(name)
        return getattr(self.base, name)

    def sample(self, n: int, seed: int | np.random.Generator) -> Scenarios:
        """The first ``n`` listed scenarios (a suite run takes all ``count``); from a generator (a
        face or trainer that refills rows), ``n`` of them drawn with replacement."""
        if isinstance(seed, np.random.Generator):
            return self.listed.take(seed.integers(0, self.listed.num, size=n))
        if not 0 <= n <= self.listed.num:
            raise ValueError(f"an explicit suite lists {self.listed.num} scenarios, {n} were asked for")
        return self.listed.take(slice(0, n))

    def to_dict(self) -> dict[str, Any]:
        return self.base.to_dict()


def in_memory(suite: Any, scenarios: Scenarios) -> Any:
    """``suite`` with ``scenarios`` as its explicit list (to run them with the runner's public calls)."""
    base = suite.distribution.base if isinstance(suite.distribution, ExplicitDistribution) else suite.distribution
    return dataclasses.replace(suite, count=scenarios.num, distribution=ExplicitDistribution(base, scenarios))


def base_distribution(suite: Any) -> ScenarioDistribution:
    d = suite.distribution
    return d.base if isinstance(d, ExplicitDistribution) else d


# ------------------------------------------------------------------ reading
def explicit_distribution(dist: ScenarioDistribution, doc: dict[str, Any], where: str) -> ExplicitDistribution:
    """The hook of ``suites.parse_suite``: the validated ``[[scenarios]]`` of ``doc`` built on ``dist``
    (its ``[scenario]`` table). Every problem is a SuiteError naming the file, the entry and the key."""
    if "base" in doc:
        raise SuiteError(f"{where}: scenarios: a suite with a base (a split or a variant) cannot list scenarios")
    if "search" in doc and not isinstance(doc["search"], dict):
        raise SuiteError(f"{where}: search: expected a table")
    entries = doc.get("scenarios")
    if not isinstance(entries, list) or not entries or not all(isinstance(e, dict) for e in entries):
        raise SuiteError(f"{where}: scenarios: expected one or more [[scenarios]] tables")
    if len(entries) != doc["count"]:
        raise SuiteError(f"{where}: count: {doc['count']} but {len(entries)} [[scenarios]] are listed")
    values = read_entries(dist, entries, where)
    try:
        scenarios = build(_layout_dist(dist, values), values)
    except (ValueError, TypeError) as exc:  # (read_entries has checked what could make these)
        raise SuiteError(f"{where}: scenarios: {exc}") from None
    return ExplicitDistribution(dist, scenarios)


def _layout_dist(dist: ScenarioDistribution, values: dict[str, np.ndarray]) -> ScenarioDistribution:
    k = int(values["oncoming_count"].max()) if "oncoming_count" in values else dist.oncoming_count
    f = int(values["follower_count"].max()) if "follower_count" in values else dist.follower_count
    return dataclasses.replace(dist, oncoming_count=k, follower_count=f)


def read_entries(dist: ScenarioDistribution, entries: list[dict[str, Any]], where: str) -> dict[str, np.ndarray]:
    """Entries -> draw values in the layout of the widest counts (``space.layout``). Each value must
    be a finite number in its range of ``dist`` (a count an integer in 0..64; ``sensor_range`` in its
    physical range)."""
    n = len(entries)
    rows_k = [_count(e, "oncoming_count", dist, where, i) for i, e in enumerate(entries)]
    rows_f = [_count(e, "follower_count", dist, where, i) for i, e in enumerate(entries)]
    per_row = sorted({key for e in entries for key in PER_ROW if key in e})
    layout_dist = dataclasses.replace(dist, oncoming_count=max(rows_k), follower_count=max(rows_f))
    K0, F0 = layout_dist.oncoming_count, layout_dist.follower_count
    plan = draw_plan(layout_dist)
    out = {d.key: np.full((n,) if d.width is None else (n, d.width), np.nan) for d in plan}
    ranges = {d.key: tuple(getattr(dist, d.field)) for d in plan}
    for key in per_row:
        out[key] = np.full(n, float(getattr(dist, key)))
    phys = {
        f.name: (f.metadata["lo"], f.metadata["hi"])
        for f in dataclasses.fields(ScenarioDistribution)
        if "lo" in f.metadata
    }
    for i, entry in enumerate(entries):
        k, f = rows_k[i], rows_f[i]
        sub_plan = draw_plan(dataclasses.replace(dist, oncoming_count=k, follower_count=f))
        allowed = {d.key for d in sub_plan} | set(COUNTS) | set(PER_ROW) | {"found"}
        unknown = sorted(set(entry) - allowed)
        if unknown:
            raise SuiteError(
                f"{where}: scenarios[{i}].{unknown[0]}: unknown key for this suite's scenarios "
                f"(known: {', '.join(sorted(allowed))})"
            )
        if "found" in entry and not isinstance(entry["found"], dict):
            raise SuiteError(f"{where}: scenarios[{i}].found: expected a table")
        for d in sub_plan:
            if d.key not in entry:
                raise SuiteError(f"{where}: scenarios[{i}].{d.key}: missing")
            lo, hi = ranges[d.key]
            v = _numbers(entry[d.key], d.width, f"{where}: scenarios[{i}].{d.key}", lo, hi)
            if d.width is None:
                out[d.key][i] = v[0]
            elif d.key == "reaction_time":
                out[d.key][i, : 1 + k] = v[: 1 + k]
                out[d.key][i, 1 + K0 : 1 + K0 + f] = v[1 + k :]
            else:
                out[d.key][i, : d.width] = v
        for key in per_row:
            if key in entry:
                lo, hi = phys[key]
                out[key][i] = _numbers(entry[key], None, f"{where}: scenarios[{i}].{key}", lo, hi)[0]
    for d in plan:  # slots a row's counts leave out: any value in range (never read)
        lo, hi = ranges[d.key]
        out[d.key] = np.where(np.isnan(out[d.key]), lo, out[d.key])
    if K0 != dist.oncoming_count or any(k != K0 for k in rows_k):
        out["oncoming_count"] = np.array(rows_k, np.int64)
    if F0 != dist.follower_count or any(f != F0 for f in rows_f):
        out["follower_count"] = np.array(rows_f, np.int64)
    return out


def _count(entry: dict[str, Any], key: str, dist: ScenarioDistribution, where: str, i: int) -> int:
    value = entry.get(key, getattr(dist, key))
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_COUNT:
        raise SuiteError(f"{where}: scenarios[{i}].{key}: expected an integer in [0, {MAX_COUNT}], got {value!r}")
    return value


def _numbers(value: Any, width: int | None, where: str, lo: float, hi: float) -> list[float]:
    values = [value] if width is None else value
    if width is not None and (not isinstance(value, list) or len(value) != width):
        raise SuiteError(f"{where}: expected a list of {width} numbers, got {value!r}")
    out = []
    for v in values:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise SuiteError(f"{where}: expected a finite number, got {v!r}")
        if not lo <= v <= hi:
            raise SuiteError(f"{where}: {v!r} is outside the [scenario] table's range [{lo:g}, {hi:g}]")
        out.append(float(v))
    return out


# ------------------------------------------------------------------ writing
def entries_of(space: Space, values: dict[str, np.ndarray]) -> list[dict[str, Any]]:
    """Draw values in the layout of ``space.dist`` -> one entry per row, each with its own widths
    (the inverse of :func:`read_entries`); counts and ``sensor_range`` only where searched."""
    dist = space.dist
    K0, F0 = dist.oncoming_count, dist.follower_count
    n = len(values["lead_gap"])
    searched = {d.key for d in space.dims}
    ks = values.get("oncoming_count", np.full(n, K0))
    fs = values.get("follower_count", np.full(n, F0))
    out = []
    for i in range(n):
        k, f = int(ks[i]), int(fs[i])
        entry: dict[str, Any] = {}
        for key in COUNTS:
            if key in searched:
                entry[key] = int(values[key][i])
        for d in draw_plan(dataclasses.replace(dist, oncoming_count=k, follower_count=f)):
            a = values[d.key][i]
            if d.width is None:
                entry[d.key] = float(a)
            elif d.key == "reaction_time":
                entry[d.key] = [float(x) for x in np.concatenate([a[: 1 + k], a[1 + K0 : 1 + K0 + f]])]
            else:
                entry[d.key] = [float(x) for x in a[: d.width]]
        for key in PER_ROW:
            if key in searched:
                entry[key] = float(values[key][i])
        out.append(entry)
    return out


def suite_tables(suite: Any) -> dict[str, Any]:
    """The ``[sim]`` table of a suite's file as written (with a base: the base's, the file's own merged over it)."""
    from overtakezoo.envs.suites import suite_document

    doc, _ = suite_document(Path(suite.path).read_bytes(), str(suite.path))
    return doc.get("sim", {})


def to_toml(header: str, doc: dict[str, Any]) -> bytes:
    """The project's one TOML writer (failure suites, the ablation's suites): small and deterministic.
    ``header`` becomes comment lines (an empty line of it stays empty: a blank line before the
    keys); then scalars and lists of scalars, then tables, then arrays of tables (each entry's own
    tables after its keys)."""
    lines = [f"# {line}".rstrip() if line else "" for line in header.splitlines()]
    lines += _table(doc, [])
    return ("\n".join(lines).strip("\n") + "\n").encode("utf-8")


def _table(table: dict[str, Any], path: list[str]) -> list[str]:
    out = [f"{_key(k)} = {_value(v)}" for k, v in table.items() if not _is_table(v) and not _is_tables(v)]
    for k, v in table.items():
        if _is_table(v):
            only_tables = v and all(_is_table(x) or _is_tables(x) for x in v.values())
            head = [] if only_tables else ["", f"[{'.'.join(map(_key, path + [k]))}]"]  # (implied by its subtables)
            out += head + _table(v, path + [k])
    for k, v in table.items():
        if _is_tables(v):
            for item in v:
                out += ["", f"[[{'.'.join(map(_key, path + [k]))}]]"] + _table(item, path + [k])
    return out


def _is_table(v: Any) -> bool:
    return isinstance(v, dict)


def _is_tables(v: Any) -> bool:
    return isinstance(v, list) and bool(v) and all(isinstance(x, dict) for x in v)


def _key(k: str) -> str:
    return k if k and all(c.isalnum() or c in "_-" for c in k) else json.dumps(k)


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        v = float(v)
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)  # the shortest text that reads back as the same double
    if isinstance(v, str):
        return json.dumps(v)  # JSON's escapes are TOML basic-string escapes
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")
