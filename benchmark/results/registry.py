"""The per-scenario metrics, each declared once (issue 38): the arrays a results file stores.

A :class:`Metric` says what its array holds (dtype, unit, a one-line doc), what a JSON null stands
for, the bounds the results schema holds each value to, where the runner takes the value from, and
its own summary row if it has one. Everything else that lists the arrays is derived from
:data:`METRICS`:

- ``schema.py``: ``PER_SCENARIO``, ``MULTI_PER_SCENARIO``, ``SAFETY_PER_SCENARIO`` and the arrays'
  part of the results JSON Schema;
- ``run/runner.py``: the arrays of each chunk, from their sources;
- ``metrics.py``: the arrays' own summary rows, their labels and units (``TABLE``, ``SAFETY_TABLE``);
- ``archive/format.py``: the episode statistics an archive stores (those of the core's ``info()``);
- docs/metrics.md's table of arrays, on the site (``tools/mkdocs_hooks.py``).

The views read :data:`METRICS` at each use, so a metric added at run time (a test's) is in every one.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass

import numpy as np

# Groups: which files hold the array.
CORE = "core"  # every file
MULTI = "multi-AV"  # multi-AV files only (num_avs >= 2)
SAFETY = "safety"  # a file has all of them or none (files from before them, or `eval --no-safety`)

# Sources: where the runner takes the value (``key``, default the name).
INFO = "info"  # OvertakeCore.info(), at the episode's end
SCENARIO = "scenario"  # the scenario's own values, read by the runner (run/runner.py: _scenario_values)
MONITOR = "monitor"  # benchmark/safety's SafetyMonitor.end_chunk()

# Aggregations of an array's own summary row.
MEAN = "mean"  # mean of the finite values, with a bootstrap 95 % interval
RATE = "rate"  # share of 1s among the values >= 0 (-1: not applicable), with a Wilson 95 % interval

FLOAT_BOUND = 1e12  # the schema's bound on any float: catches garbage, never a measured value


@dataclass(frozen=True)
class Summary:
    """An array's own row in a results summary and its table (metrics.py)."""

    label: str  # the row's label in the metrics tables
    aggregate: str = MEAN
    over: str = "all"  # the scenarios it is taken over: "all", "successes" or "failures"
    key: str = ""  # its key in the summary, when not the array's name
    percent: bool = False  # a mean of shares, shown as a percentage


@dataclass(frozen=True)
class Metric:
    """One per-scenario array of a results file."""

    name: str
    group: str  # CORE, MULTI or SAFETY
    dtype: type  # np.int8, np.int64 or np.float64
    unit: str  # "" for counts, codes, flags, indices and shares
    doc: str  # one line: what a value is
    null: float | None = None  # what a JSON null stands for (float arrays: NaN or inf; int arrays have none)
    bounds: tuple[float, float] = (-FLOAT_BOUND, FLOAT_BOUND)  # the schema's minimum and maximum of a value
    source: str = INFO
    key: str = ""  # the source's key, when not the name
    summary: Summary | None = None

    def __post_init__(self) -> None:
        floating = self.dtype is np.float64
        if floating != (self.null is not None):
            raise ValueError(f"metric {self.name}: a float array needs a null (NaN or inf), an int array none")

    @property
    def source_key(self) -> str:
        return self.key or self.name

    @property
    def summary_key(self) -> str | None:
        return None if self.summary is None else self.summary.key or self.name

    def table_row(self) -> tuple[str, str, str, str]:
        """Its summary row as metrics.TABLE lists rows: (key, label, kind, unit); kind "rate" prints as %."""
        s = self.summary
        assert s is not None, self.name
        rate = s.aggregate == RATE or s.percent
        return (self.summary_key, s.label, "rate" if rate else "mean", "%" if rate else self.unit)

    def items_schema(self) -> dict:
        """The JSON Schema of one value (schema.py checks these with numpy)."""
        lo, hi = self.bounds
        kind = "integer" if self.dtype is not np.float64 else ["number", "null"]
        return {"type": kind, "minimum": lo, "maximum": hi}


NAN, INF = math.nan, math.inf
_S, _COUNT = "s", (0, 1_000_000_000)

METRICS: tuple[Metric, ...] = (
    # ---------------------------------------------------------------- core: the core's own statistics
    Metric("outcome", CORE, np.int8, "", "how it ended: 1 success, 2 crash, 3 timeout, 4 off-road", bounds=(0, 4)),
    Metric("crash_npc", CORE, np.int64, "", "the NPC slot the AV crashed into (-1: none)", bounds=(-1, 4096)),
    Metric("crash_lane", CORE, np.int64, "", "that NPC's lane: 0 the AV's, 1 the opposite (-1: none)", bounds=(-1, 1)),
    Metric(
        "completion_time",
        CORE,
        np.float64,
        _S,
        "episode time at success (NaN otherwise)",
        NAN,
        summary=Summary("completion time of successes", over="successes"),
    ),
    Metric("episode_time", CORE, np.float64, _S, "episode time at the end", NAN, key="t"),
    Metric(
        "aborts",
        CORE,
        np.int64,
        "",
        "aborts of an overtake under way (ABORT right after OVERTAKE)",
        bounds=_COUNT,
        summary=Summary("aborts per scenario"),
    ),
    Metric("switches", CORE, np.int64, "", "switches into or out of OVERTAKE", bounds=_COUNT),
    Metric(
        "opposite_time",
        CORE,
        np.float64,
        _S,
        "time with the AV's body across the centre line",
        NAN,
        summary=Summary("time in the opposite lane"),
    ),
    Metric(
        "min_ttc",
        CORE,
        np.float64,
        _S,
        "least time to collision with a vehicle ahead on the AV's path (inf: never closing)",
        INF,
        summary=Summary("min time-to-collision (scenarios with one)"),
    ),
    Metric(
        "peak_lat_accel",
        CORE,
        np.float64,
        "m/s^2",
        "largest lateral acceleration",
        NAN,
        summary=Summary("peak lateral acceleration"),
    ),
    Metric(
        "peak_jerk",
        CORE,
        np.float64,
        "m/s^3",
        "largest longitudinal jerk",
        NAN,
        summary=Summary("peak longitudinal jerk"),
    ),
    # the paper's "mean NPC speed in failed scenarios" rows
    Metric(
        "npc1_speed",
        CORE,
        np.float64,
        "m/s",
        "initial speed of NPC1, the lead (multi-AV: the AV's own lead; NaN none)",
        NAN,
        source=SCENARIO,
        summary=Summary("mean NPC1 speed in failed scenarios", over="failures", key="npc1_speed_failed"),
    ),
    Metric(
        "npc2_speed",
        CORE,
        np.float64,
        "m/s",
        "initial speed of NPC2, the first oncoming vehicle (NaN in multi-AV files)",
        NAN,
        source=SCENARIO,
        summary=Summary("mean NPC2 speed in failed scenarios", over="failures", key="npc2_speed_failed"),
    ),
    # ---------------------------------------------------------------- multi-AV files
    Metric("crash_av", MULTI, np.int64, "", "the other AV a crash was with (its index), -1 none", bounds=(-1, 63)),
    Metric(
        "lead_npc",
        MULTI,
        np.int64,
        "",
        "the NPC slot of the AV's own lead (its NPC1), -1 none",
        bounds=(-1, 4096),
        source=SCENARIO,
    ),
    # ---------------------------------------------------------------- safety (issue 22; docs/metrics.md)
    Metric(
        "rss_violation_share",
        SAFETY,
        np.float64,
        "",
        "share of the AV's opposite-lane time in RSS Def. 2 violation (NaN: never in the opposite lane)",
        NAN,
        source=MONITOR,
        summary=Summary("share of opposite-lane time in RSS violation", percent=True),
    ),
    Metric(
        "rss_first_violation",
        SAFETY,
        np.float64,
        _S,
        "episode time of the first RSS Def. 2 violation (NaN: none)",
        NAN,
        source=MONITOR,
        summary=Summary("time of the first RSS violation"),
    ),
    Metric(
        "rss_worst_margin",
        SAFETY,
        np.float64,
        "m",
        "least gap minus RSS Def. 2 distance over opposite-lane steps with an oncoming vehicle (NaN: none)",
        NAN,
        source=MONITOR,
        summary=Summary("worst RSS margin in the opposite lane"),
    ),
    Metric(
        "rss_merge_violation",
        SAFETY,
        np.int8,
        "",
        "RSS Def. 1 violated at a merge back: 1, not: 0, no merge back: -1",
        bounds=(-1, 1),
        source=MONITOR,
        summary=Summary("RSS (same direction) violated at the merge back, of merges", RATE),
    ),
    Metric(
        "min_headon_ttc",
        SAFETY,
        np.float64,
        _S,
        "least head-on time to collision in the opposite lane (inf: never closing head-on)",
        INF,
        source=MONITOR,
        summary=Summary("min head-on time-to-collision (scenarios closing head-on)"),
    ),
    Metric(
        "cutin_pet",
        SAFETY,
        np.float64,
        _S,
        "least post-encroachment time at a merge back in front of a vehicle (NaN: none)",
        NAN,
        source=MONITOR,
        summary=Summary("post-encroachment time at the cut-in"),
    ),
    Metric(
        "abort_delay",
        SAFETY,
        np.float64,
        _S,
        "time from the first visible-and-unsafe overtake state to the abort decision (NaN: none)",
        NAN,
        source=MONITOR,
        summary=Summary("abort delay after the overtake became unsafe"),
    ),
    Metric(
        "late_abort",
        SAFETY,
        np.int8,
        "",
        "late abort, or an unaborted unsafe overtake that violated RSS: 1, timely: 0, never unsafe: -1",
        bounds=(-1, 1),
        source=MONITOR,
        summary=Summary("late or missing abort, of unsafe overtakes", RATE),
    ),
    Metric(
        "ponr_margin",
        SAFETY,
        np.float64,
        _S,
        "least point-of-no-return margin over the overtake (NaN: no overtake with an oncoming vehicle)",
        NAN,
        source=MONITOR,
        summary=Summary("point-of-no-return margin"),
    ),
)


def metrics(*groups: str) -> list[Metric]:
    """The metrics of ``groups`` (all when none), in declaration order (the order of a file's arrays)."""
    return [m for m in METRICS if not groups or m.group in groups]


def recorded(num_avs: int = 1, safety: bool = True) -> list[Metric]:
    """The metrics a run records: the core ones, the multi-AV ones on multi-AV suites, the safety ones
    unless ``eval --no-safety``."""
    return metrics(CORE, *([MULTI] if num_avs > 1 else []), *([SAFETY] if safety else []))


class ArraysView(Mapping[str, tuple[type, float | None]]):
    """name -> (dtype, null) of the arrays of ``groups``, read from :data:`METRICS` at each use."""

    def __init__(self, *groups: str) -> None:
        self.groups = groups

    def _now(self) -> dict[str, tuple[type, float | None]]:
        return {m.name: (m.dtype, m.null) for m in metrics(*self.groups)}

    def __getitem__(self, key: str) -> tuple[type, float | None]:
        return self._now()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._now())

    def __len__(self) -> int:
        return len(self._now())

    def __repr__(self) -> str:
        return f"ArraysView{self.groups}: {self._now()!r}"


def docs_table() -> str:
    """The Markdown table of every array (docs/metrics.md on the site, by tools/mkdocs_hooks.py)."""
    sources = {INFO: "`OvertakeCore.info()['{}']`", SCENARIO: "the scenario (runner)", MONITOR: "`SafetyMonitor`"}
    lines = [
        "| array | group | type | null | unit | summary row | source | what a value is |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for m in METRICS:
        null = "never null" if m.null is None else ("inf" if m.null == math.inf else "NaN")
        row = "—" if m.summary is None else f"`{m.summary_key}`: {m.summary.label} ({_aggregation(m.summary)})"
        source = sources[m.source].format(m.source_key)
        cells = [f"`{m.name}`", m.group, np.dtype(m.dtype).name, null, m.unit or "—", row, source, m.doc]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _aggregation(s: Summary) -> str:
    what = "share of 1s among the applicable" if s.aggregate == RATE else "mean of the finite values"
    return what if s.over == "all" else f"{what}, over {s.over}"
