"""The leaderboard's success-vs-crash pictures (one per suite page)."""

from __future__ import annotations

import io
from typing import Any

from overtakezoo.benchmark.leaderboard.rows import Row
from overtakezoo.benchmark.leaderboard.untrusted import plot_text


def rate_plot(
    name: str,
    ranked: list[Row],
    bounds: list[Row],
    x_of: Any = None,
    y_of: Any = None,
    labels: tuple[str, str, str] = ("success rate (%)", "crash rate (%)", "success and crash rate"),
) -> bytes:
    """Success and crash rate with Wilson CIs, one row per decider in rank order (upper bounds last),
    two panels sharing the names on the y axis: a dot plot, so no label can hide another however
    close the rates are. Agg canvas, no pyplot state, no timestamps in the PNG. ``x_of`` / ``y_of``
    pick other rates from a summary (multi-AV suites plot joint outcomes)."""
    x_of = x_of or (lambda s: s["success_rate"])
    y_of = y_of or (lambda s: s["crash_rate"])
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    rows = ranked + bounds
    names = [plot_text(r.name) + (" (upper bound)" if r.privileged else "") for r in rows]
    with matplotlib.rc_context({"svg.hashsalt": "overtakezoo", "font.family": "DejaVu Sans", "font.size": 9}):
        fig = Figure(figsize=(7.5, 1.2 + 0.24 * max(len(rows), 1)), dpi=100)
        FigureCanvasAgg(fig)
        axes = fig.subplots(1, 2, sharey=True)
        y = list(range(len(rows)))
        for ax, rate_of, label in ((axes[0], x_of, labels[0]), (axes[1], y_of, labels[1])):
            for i, row in enumerate(rows):
                r = rate_of(row.results.summary)
                v = 100 * r["value"]
                # max(0, .): a Wilson bound can sit a rounding error beyond the rate it brackets.
                err = [[max(0.0, v - 100 * r["lo"])], [max(0.0, 100 * r["hi"] - v)]]
                ax.errorbar(
                    [v],
                    [i],
                    xerr=err,
                    fmt="s" if row.privileged else "o",
                    capsize=2,
                    markersize=4,
                    color="C1" if row.privileged else "C0",
                    mfc="none" if row.privileged else None,
                )
            ax.set_xlim(-3, 103)
            ax.set_xlabel(label)
            ax.grid(True, axis="x", alpha=0.3)
        axes[0].set_yticks(y, names)
        axes[0].set_ylim(len(rows) - 0.5, -0.5)  # the best ranked on top
        fig.suptitle(f"{plot_text(name)}: {labels[2]} (95 % CI), measured", fontsize=10)
        fig.tight_layout()
        buf = io.BytesIO()
        fig.savefig(buf, format="png", metadata={"Software": None})
    return buf.getvalue()
