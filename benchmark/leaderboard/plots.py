"""The leaderboard's success-vs-crash pictures (one per suite page)."""

from __future__ import annotations

import io
from typing import Any

from overtakezoo.benchmark.leaderboard.rows import Row
from overtakezoo.benchmark.leaderboard.untrusted import plot_text


def rate_plot(name: str, ranked: list[Row], bounds: list[Row], x_of: Any = None, y_of: Any = None,
          labels: tuple[str, str, str] = ("success rate (%)", "crash rate (%)", "success vs crash rate")) -> bytes:
    """Success vs crash rate with Wilson CIs; Agg canvas, no pyplot state, no timestamps in the PNG.
    ``x_of`` / ``y_of`` pick other rates from a summary (multi-AV suites plot joint outcomes)."""
    x_of = x_of or (lambda s: s["success_rate"])
    y_of = y_of or (lambda s: s["crash_rate"])
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    with matplotlib.rc_context({"svg.hashsalt": "overtakezoo", "font.family": "DejaVu Sans", "font.size": 9}):
        fig = Figure(figsize=(6.0, 4.5), dpi=100)
        FigureCanvasAgg(fig)
        ax = fig.add_subplot(1, 1, 1)
        for i, row in enumerate(ranked + bounds):
            r, label = row.results, plot_text(row.name) + (" (upper bound)" if row.privileged else "")
            s, c = x_of(r.summary), y_of(r.summary)
            x, y = 100 * s["value"], 100 * c["value"]
            # max(0, .): a Wilson bound can sit a rounding error beyond the rate it brackets.
            xerr = [[max(0.0, x - 100 * s["lo"])], [max(0.0, 100 * s["hi"] - x)]]
            yerr = [[max(0.0, y - 100 * c["lo"])], [max(0.0, 100 * c["hi"] - y)]]
            ax.errorbar([x], [y], xerr=xerr, yerr=yerr, fmt="s" if row.privileged else "o", capsize=3,
                        color=f"C{i % 10}", label=label, mfc="none" if row.privileged else None)
            ax.annotate(plot_text(row.name), (x, y), textcoords="offset points", xytext=(5, 5))
        ax.set_xlim(-5, 105)
        ax.set_ylim(-5, 105)
        ax.set_xlabel(labels[0])
        ax.set_ylabel(labels[1])
        ax.set_title(f"{plot_text(name)}: {labels[2]} (95 % CI), measured")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
        fig.tight_layout()
        buf = io.BytesIO()
        fig.savefig(buf, format="png", metadata={"Software": None})
    return buf.getvalue()
