"""The paper's Table I beside ours: every row for the paper's RL (DQN) and OpenPlanner-only columns
next to our ``dqn`` and ``rule-fsm`` on ``table1``, with CIs, and per row whether the paper's shape
(which column is higher) holds here. Pure function of summaries (data in, Markdown out).

The verdict is computed: the paper's direction (RL above, below or level with OP; level when the
two differ by less than ``_LEVEL``) against ours (above or below when the 95 % CIs do not overlap,
level when they do). The reason, where the shape does not hold, is a sentence from
``reference/table1-shape.json`` (hand-written after reading the data); it is printed only when
its recorded verdict matches the computed one, so a stale explanation never shows.
"""

from __future__ import annotations

from typing import Any

from overtakezoo.benchmark.leaderboard.untrusted import md
from overtakezoo.benchmark.results.metrics import TABLE, format_metric

_LEVEL = {
    "success_rate": 0.02,
    "completion_time": 0.3,
    "crash_share_npc1": 0.05,
    "crash_share_npc2": 0.05,
    "npc1_speed_failed": 0.15,
    "npc2_speed_failed": 0.15,
}
ROWS = [
    "success_rate",
    "completion_time",
    "crash_share_npc1",
    "crash_share_npc2",
    "crash_same_scenarios",
    "npc1_speed_failed",
    "npc2_speed_failed",
]
_KIND = {k: (label, kind, unit) for k, label, kind, unit in TABLE}


def _paper_direction(key: str, rl: float, op: float) -> str:
    if abs(rl - op) < _LEVEL[key]:
        return "level"
    return "above" if rl > op else "below"


def _our_direction(a: dict[str, Any] | None, b: dict[str, Any] | None) -> str | None:
    if not a or not b or a.get("value") is None or b.get("value") is None:
        return None
    if a["lo"] is not None and b["hi"] is not None and a["lo"] > b["hi"]:
        return "above"
    if a["hi"] is not None and b["lo"] is not None and a["hi"] < b["lo"]:
        return "below"
    return "level"


def verdicts(
    paper_rl: dict[str, Any], paper_op: dict[str, Any], dqn: dict[str, Any], fsm: dict[str, Any]
) -> dict[str, tuple[str | None, str | None]]:
    """Per row: (paper's direction of RL vs OP, ours of dqn vs rule-fsm)."""
    out = {}
    for key in ROWS:
        if key not in _LEVEL:
            out[key] = (None, None)
            continue
        rl, op = paper_rl.get(key), paper_op.get(key)
        paper = _paper_direction(key, rl, op) if rl is not None and op is not None else None
        out[key] = (paper, _our_direction(dqn.get(key), fsm.get(key)))
    return out


def _reported(value: Any, kind: str, unit: str) -> str:
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return "-"
    return f"{value * 100:.1f} %" if kind == "rate" else f"{value:.1f} {unit}".strip()


def render(
    reference: dict[str, Any],
    dqn: dict[str, Any],
    fsm: dict[str, Any],
    paired: dict[str, Any] | None,
    notes: dict[str, Any],
    labels: tuple[str, str] = ("dqn", "rule-fsm"),
) -> str:
    """Markdown: the side-by-side table and one sentence per row. ``reference`` is paper.json;
    ``dqn`` / ``fsm`` are results summaries on table1; ``paired`` is crash-in-the-same-scenarios."""
    rl, op = reference["rows"][0], reference["rows"][1]
    v = verdicts(rl, op, dqn, fsm)
    out = [
        f"| Table I row | paper: {md(rl['decider'])} | ours: {labels[0]} | paper: {md(op['decider'])} | "
        f"ours: {labels[1]} | shape |",
        "|---|---|---|---|---|---|",
    ]
    sentences = []
    for key in ROWS:
        label, kind, unit = _KIND[key]
        if key == "crash_same_scenarios":
            ours = format_metric(paired, kind, unit)
            cells = [_reported(rl.get(key), kind, unit), ours, _reported(op.get(key), kind, unit), ours]
            shape = "paired"
        else:
            cells = [
                _reported(rl.get(key), kind, unit),
                format_metric(dqn.get(key), kind, unit),
                _reported(op.get(key), kind, unit),
                format_metric(fsm.get(key), kind, unit),
            ]
            paper, ours = v[key]
            shape = "-" if ours is None else ("holds" if paper == ours else "differs")
            if paper is not None and ours is not None:
                shape += f" (paper: RL {paper} OP; ours: {labels[0]} {ours} {labels[1]})"
        out.append(f"| {label} | " + " | ".join(cells) + f" | {shape} |")
        note = notes.get(key)
        if isinstance(note, dict) and note.get("shape") == shape.split(" ")[0] and note.get("text"):
            sentences.append(f"- **{label}**: {md(note['text'])}")
        else:
            sentences.append(f"- **{label}**: {shape.split(' ')[0]}; no explanation recorded for this result.")
    return "\n".join(out + [""] + sentences) + "\n"
