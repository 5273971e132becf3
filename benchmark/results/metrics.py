"""Table I metrics with 95 % confidence intervals, computed from per-scenario arrays.

Rates get Wilson score intervals; means get a seeded percentile bootstrap, so a summary is a pure
function of the per-scenario arrays and the seed (shards merged give the single run's summary).
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Sequence
from typing import Any

import numpy as np

from overtakezoo.benchmark.results import registry
from overtakezoo.envs import CRASH, OFFROAD, SUCCESS, TIMEOUT
from overtakezoo.envs.scenarios import OPPOSITE_LANE, crash_roles

Z95 = 1.959963984540054  # two-sided 95 % normal quantile
BOOTSTRAP_SAMPLES = 1000
_BLOCK = 4_000_000  # resampled values held in memory at once

# A table's rows are (key, label, kind, unit): kind "rate" prints as %, "mean" with its unit. A row
# computed from several arrays (summarize) is written out below; a name is an array's own row (its
# label and unit declared in registry.py). After these come the group's other own rows in declaration
# order, so a newly declared metric's row appears without an edit here.
TABLE_LAYOUT: list[tuple[str, str, str, str] | str] = [
    ("success_rate", "successful overtaking", "rate", "%"),
    "completion_time",
    ("crash_share_npc1", "share of crashes with NPC1 (ahead)", "rate", "%"),
    ("crash_share_npc2", "share of crashes with NPC2 (oncoming)", "rate", "%"),
    ("crash_same_scenarios", "crash in the same scenarios", "rate", "%"),
    "npc1_speed_failed",
    "npc2_speed_failed",
    ("crash_rate", "crash rate", "rate", "%"),
    ("timeout_rate", "timeout rate", "rate", "%"),
    ("offroad_rate", "off-road rate", "rate", "%"),
    ("crash_share_other", "share of crashes with other vehicles", "rate", "%"),
    ("crash_share_opposite_lane", "share of crashes in the opposite lane", "rate", "%"),
]  # then aborts, opposite_time, min_ttc, peak_lat_accel, peak_jerk
PAIRED = {"crash_same_scenarios"}  # needs two results
# The safety metrics (issue 22, docs/metrics.md): in a summary only when its arrays are in the file,
# and a table of their own, so Table I (and every page rendering it) stays as it was.
SAFETY_LAYOUT: list[tuple[str, str, str, str] | str] = [
    ("rss_violation_rate", "RSS (opposite direction) violated, of scenarios in the opposite lane", "rate", "%"),
]  # then the safety arrays' own rows


class TableRows(Sequence[tuple[str, str, str, str]]):
    """A table's rows: ``layout``, then the other own rows of ``group``'s arrays; read from the
    registry at each use, so a metric declared (or added by a test) later is in it."""

    def __init__(self, group: str, layout: list[tuple[str, str, str, str] | str]) -> None:
        self.group, self.layout = group, layout

    def _rows(self) -> list[tuple[str, str, str, str]]:
        own = {m.summary_key: m.table_row() for m in registry.metrics(self.group) if m.summary is not None}
        placed = [own.pop(row) if isinstance(row, str) else row for row in self.layout]
        return [*placed, *own.values()]

    def __getitem__(self, i: Any) -> Any:  # an index or a slice, as a list's
        return self._rows()[i]

    def __len__(self) -> int:
        return len(self._rows())

    def __add__(self, other: list[tuple[str, str, str, str]]) -> list[tuple[str, str, str, str]]:
        return [*self._rows(), *other]

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Sequence) and self._rows() == list(other)

    def __repr__(self) -> str:
        return repr(self._rows())


TABLE = TableRows(registry.CORE, TABLE_LAYOUT)
SAFETY_TABLE = TableRows(registry.SAFETY, SAFETY_LAYOUT)


def wilson(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval for k successes in n trials (NaN when n == 0)."""
    if n == 0:
        return math.nan, math.nan
    p, z2 = k / n, z * z
    denom = 1.0 + z2 / n
    centre = (p + z2 / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n)) / denom
    return max(0.0, centre - half), min(1.0, centre + half)


def bootstrap_mean(x: np.ndarray, seed: Any, samples: int = BOOTSTRAP_SAMPLES) -> tuple[float, float]:
    """Percentile bootstrap 95 % interval of the mean of ``x`` (NaN when empty)."""
    x = np.asarray(x, dtype=float)
    m = x.shape[0]
    if m == 0:
        return math.nan, math.nan
    rng = np.random.default_rng(seed)
    rows = max(1, _BLOCK // m)
    means = np.concatenate(
        [x[rng.integers(0, m, size=(min(rows, samples - b), m))].mean(axis=1) for b in range(0, samples, rows)]
    )
    lo, hi = np.percentile(means, [2.5, 97.5])
    return float(lo), float(hi)


def _rate(mask: np.ndarray, within: np.ndarray | None = None) -> dict[str, Any]:
    k, n = (
        int(np.count_nonzero(mask if within is None else mask & within)),
        int(mask.shape[0] if within is None else np.count_nonzero(within)),
    )
    lo, hi = wilson(k, n)
    return {"value": k / n if n else None, "lo": _num(lo), "hi": _num(hi), "k": k, "n": n}


def _mean(x: np.ndarray, seed: int, key: str) -> dict[str, Any]:
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    lo, hi = bootstrap_mean(x, [seed, zlib.crc32(key.encode())])  # a stream per metric
    return {"value": float(x.mean()) if x.size else None, "lo": _num(lo), "hi": _num(hi), "n": int(x.size)}


def _num(v: float) -> float | None:
    return None if not math.isfinite(v) else float(v)


def summarize(per: dict[str, np.ndarray], seed: int) -> dict[str, dict[str, Any]]:
    """Every single-result metric of :data:`TABLE` from the per-scenario arrays, and of
    :data:`SAFETY_TABLE` when the safety arrays are in ``per``."""
    outcome, npc, lane = per["outcome"], per["crash_npc"], per["crash_lane"]
    success, crash = outcome == SUCCESS, outcome == CRASH
    npc1, npc2 = crash_roles(npc, lane, per.get("lead_npc"))
    derived = {
        "success_rate": _rate(success),
        "crash_share_npc1": _rate(npc1, crash),
        "crash_share_npc2": _rate(npc2, crash),
        "crash_rate": _rate(crash),
        "timeout_rate": _rate(outcome == TIMEOUT),
        "offroad_rate": _rate(outcome == OFFROAD),
        "crash_share_other": _rate(~npc1 & ~npc2, crash),
        "crash_share_opposite_lane": _rate(lane == OPPOSITE_LANE, crash),
    }
    if "rss_violation_share" in per:  # rates count within the scenarios the metric applies to
        share = per["rss_violation_share"]
        derived["rss_violation_rate"] = _rate(share > 0, ~np.isnan(share))
    scenarios = {"all": slice(None), "successes": success, "failures": ~success}
    own = {
        m.summary_key: _own_row(per[m.name][scenarios[m.summary.over]], m.summary, m.summary_key, seed)
        for m in registry.metrics()
        if m.summary is not None and (m.group == registry.CORE or m.name in per)
    }
    return {**derived, **own}


def _own_row(x: np.ndarray, how: registry.Summary, key: str, seed: int) -> dict[str, Any]:
    """An array's own summary row. Means leave out undefined values (NaN) and infinite ones (min_ttc:
    never on a collision course); rates count the 1s among the values that apply (>= 0)."""
    if how.aggregate == registry.RATE:
        return _rate(x == 1, x >= 0)
    return _mean(x, seed, key)


def crash_same_scenarios(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> dict[str, Any]:
    """Share of scenarios in which both results crashed (the paper's paired row)."""
    if a["outcome"].shape != b["outcome"].shape:
        raise ValueError("paired metrics need results over the same scenarios")
    return _rate((a["outcome"] == CRASH) & (b["outcome"] == CRASH))


def format_metric(m: dict[str, Any] | None, kind: str, unit: str) -> str:
    """``"92.2 % [91.2, 93.1]"`` or ``"27.9 s [27.6, 28.2]"``; ``-`` when undefined."""
    if not m or m.get("value") is None:
        return "-"
    scale, unit = (100.0, "%") if kind == "rate" else (1.0, unit)
    value = f"{m['value'] * scale:.1f}" if kind == "rate" else f"{m['value']:.2f}"
    if m.get("lo") is None:
        return f"{value} {unit}".strip()
    if kind == "rate":
        return f"{value} {unit} [{m['lo'] * scale:.1f}, {m['hi'] * scale:.1f}]"
    return f"{value} {unit} [{m['lo']:.2f}, {m['hi']:.2f}]".replace("  ", " ")


def render_table(
    columns: list[tuple[str, dict[str, Any]]],
    paired: dict[str, Any] | None = None,
    markdown: bool = False,
    table: list[tuple[str, str, str, str]] | None = None,
) -> str:
    """Table I: one row per metric, one column per (header, summary). ``paired`` fills the
    "crash in the same scenarios" row (it exists only for two results). ``table``: other rows
    (multi_metrics.MULTI_TABLE) than :data:`TABLE`."""
    headers = ["metric", *[h for h, _ in columns]]
    rows = []
    for key, label, kind, unit in table or TABLE:
        if key in PAIRED:
            if paired is None:
                continue
            cells = [format_metric(paired, kind, unit)] * len(columns)
        else:
            cells = [format_metric(s.get(key), kind, unit) for _, s in columns]
        rows.append([label, *cells])
    if markdown:
        lines = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
        return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows]) + "\n"
    widths = [max(len(r[i]) for r in [headers, *rows]) for i in range(len(headers))]
    fmt = lambda r: "  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip()  # noqa: E731
    return "\n".join([fmt(headers), fmt(["-" * w for w in widths]), *map(fmt, rows)]) + "\n"
