"""The leaderboard's safety pages: a *Safety* table per suite, the RSS shield's trade-off, and the
score page's safety column (metrics defined in docs/metrics.md, measured by benchmark/safety/)."""

from __future__ import annotations

import io

import numpy as np

from overtakezoo.benchmark.leaderboard.rows import Row
from overtakezoo.benchmark.leaderboard.untrusted import md, md_image, plot_text
from overtakezoo.benchmark.results.metrics import SAFETY_TABLE, format_metric

# The columns of a suite's Safety table: what an AV engineer asks of an overtake first.
COLUMNS = (
    "rss_violation_rate",
    "rss_violation_share",
    "rss_worst_margin",
    "rss_merge_violation",
    "late_abort",
    "min_headon_ttc",
    "ponr_margin",
)
_SPEC = {k: (label, kind, unit) for k, label, kind, unit in SAFETY_TABLE}
SHIELD = "+shield"
INTRO = (
    "RSS: the minimal safe longitudinal distances of Shalev-Shwartz, Shammah and Shashua (2017), "
    "Definition 2 (opposite directions) while the ego is in the opposite lane, Definition 1 (same "
    "direction) at the merge back, with the parameters of docs/metrics.md. A decider that never crashes "
    "can still live in RSS violation: this table shows it. Rates with 95 % Wilson intervals, means with "
    "bootstrap intervals; `-` where a metric does not apply (e.g. no overtake)."
)


def has_safety(row: Row) -> bool:
    return "rss_violation_rate" in row.results.summary


def safety_section(rows: list[Row], title: str = "## Safety") -> list[str]:
    """The Safety table of a suite page (rows without safety arrays are listed as not measured)."""
    if not rows:
        return []
    head = ["name", *[_SPEC[k][0] for k in COLUMNS]]
    out = [title, "", INTRO, "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        s = row.results.summary
        label = md(row.name) + (" (upper bound)" if row.privileged else "")
        cells = (
            [format_metric(s.get(k), _SPEC[k][1], _SPEC[k][2]) for k in COLUMNS]
            if has_safety(row)
            else ["not measured (recorded before the safety metrics)"] + ["-"] * (len(COLUMNS) - 1)
        )
        out.append("| " + " | ".join([label, *cells]) + " |")
    return out + [""]


def shield_pairs(rows: list[Row]) -> list[tuple[Row, Row]]:
    """(decider, the same decider behind the shield) for every shielded row with its plain row."""
    by_name = {row.name: row for row in rows}
    return [
        (by_name[r.name[: -len(SHIELD)]], r)
        for r in rows
        if r.name.endswith(SHIELD) and r.name[: -len(SHIELD)] in by_name
    ]


def shield_section(rows: list[Row]) -> list[str]:
    """Each shielded row beside its plain decider on one suite."""
    pairs = shield_pairs(rows)
    if not pairs:
        return []
    keys = (
        ("success_rate", "rate", "%"),
        ("crash_rate", "rate", "%"),
        ("rss_violation_rate", "rate", "%"),
        ("late_abort", "rate", "%"),
    )
    head = ["decider", *[f"{lab} (plain / shielded)" for lab in ("success", "crash", "RSS violated", "late abort")]]
    out = [
        "### Behind the RSS shield",
        "",
        "`<name>+shield` is the same decider behind the RSS shield (`zoo/members/shield.py`, Alshiekh et al. 2018): an "
        "overtake that cannot keep the RSS opposite-direction distance to the oncoming vehicle it sees is "
        "vetoed, or aborted while the lead is not yet passed. A shield that stops a decider from overtaking "
        "shows as lost success.",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
    ]
    for plain, shielded in pairs:
        cells = [
            f"{format_metric(plain.results.summary.get(k), kind, unit)} / "
            f"{format_metric(shielded.results.summary.get(k), kind, unit)}"
            for k, kind, unit in keys
        ]
        out.append("| " + " | ".join([md(plain.name), *cells]) + " |")
    return out + [""]


def core_means(live_rows: dict[str, list[Row]], suites: tuple[str, ...]) -> dict[str, dict[str, float]]:
    """Per row name present on every suite of ``suites``: the mean over them of success, crash and
    RSS violation rates (the last only where every row has safety arrays)."""
    names = set.intersection(*[{r.name for r in live_rows.get(s, [])} for s in suites]) if suites else set()
    out: dict[str, dict[str, float]] = {}
    for name in sorted(names):
        rows = [next(r for r in live_rows[s] if r.name == name) for s in suites]
        val = lambda k, rows=rows: float(np.mean([r.results.summary[k]["value"] or 0.0 for r in rows]))  # noqa: E731
        out[name] = {
            "success": val("success_rate"),
            "crash": val("crash_rate"),
            "rss": val("rss_violation_rate") if all(has_safety(r) for r in rows) else float("nan"),
        }
    return out


def readme_section(means: dict[str, dict[str, float]], suites: tuple[str, ...]) -> tuple[list[str], bytes | None]:
    """The index page's shield section and its trade-off plot (``shield.png``), over ``suites``."""
    pairs = [(n[: -len(SHIELD)], n) for n in means if n.endswith(SHIELD) and n[: -len(SHIELD)] in means]
    if not pairs:
        return [], None
    pct = lambda x: "-" if np.isnan(x) else f"{100 * x:.1f}"  # noqa: E731
    out = [
        "## Safety and the RSS shield",
        "",
        f"Mean over the `core` suites ({', '.join(f'`{s}`' for s in suites)}) of each rate, in %, for every zoo "
        "member that overtakes, plain and behind the RSS shield (`<name>+shield`, `zoo/members/shield.py`). *RSS "
        "violated*: share of the scenarios with time in the opposite lane in which the RSS opposite-direction "
        "distance was broken at least once (docs/metrics.md). Each suite's page has the full Safety table. "
        "Learned members here are their shipped seed's rows.",
        "",
        "| decider | success | crash | RSS violated | success (shielded) | crash (shielded) | "
        "RSS violated (shielded) |",
        "|---|---|---|---|---|---|---|",
    ]
    for plain, shielded in pairs:
        a, b = means[plain], means[shielded]
        out.append(
            f"| {md(plain)} | {pct(a['success'])} | {pct(a['crash'])} | {pct(a['rss'])} | "
            f"{pct(b['success'])} | {pct(b['crash'])} | {pct(b['rss'])} |"
        )
    out += ["", md_image("success against crash and RSS violation, plain and shielded", "shield.png"), ""]
    return out, _plot(pairs, means)


def _plot(pairs: list[tuple[str, str]], means: dict[str, dict[str, float]]) -> bytes:
    """Two panels (success against crash rate; against RSS violation), an arrow from each decider
    to its shielded self. Labels are placed by a fixed vertical offset order, never on a point."""
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    with matplotlib.rc_context({"svg.hashsalt": "overtakezoo", "font.family": "DejaVu Sans", "font.size": 8}):
        fig = Figure(figsize=(10.0, 4.6), dpi=100)
        FigureCanvasAgg(fig)
        for j, (key, xlabel) in enumerate((("crash", "crash rate (%)"), ("rss", "RSS violated (% of overtakes)"))):
            ax = fig.add_subplot(1, 2, j + 1)
            for i, (plain, shielded) in enumerate(pairs):
                a, b = means[plain], means[shielded]
                x0, y0, x1, y1 = 100 * a[key], 100 * a["success"], 100 * b[key], 100 * b["success"]
                if np.isnan(x0) or np.isnan(x1):
                    continue
                color = f"C{i % 10}"
                ax.annotate("", (x1, y1), (x0, y0), arrowprops={"arrowstyle": "->", "color": color, "lw": 1.2})
                ax.plot([x0], [y0], "o", color=color, mfc="none", label=plot_text(plain) if j == 0 else None)
                ax.plot([x1], [y1], "o", color=color)
            ax.set_xlabel(xlabel)
            ax.set_ylabel("success rate (%)")
            ax.grid(alpha=0.3)
        fig.legend(loc="center right", title="open: plain, filled: shielded", frameon=False)
        fig.suptitle("The RSS shield's trade-off (mean over the core suites)")
        fig.subplots_adjust(left=0.06, right=0.82, wspace=0.25)
        buf = io.BytesIO()
        fig.savefig(buf, format="png", metadata={"Software": None})
        return buf.getvalue()


def safety_column(means: dict[str, dict[str, float]]) -> dict[str, str]:
    """The score page's safety column: the mean RSS violation rate over the core suites, in %."""
    return {n: ("-" if np.isnan(m["rss"]) else f"{100 * m['rss']:.1f}") for n, m in means.items()}
