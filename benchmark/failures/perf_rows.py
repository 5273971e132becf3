"""The failure search's rows of the performance report (``overtakezoo perf``; benchmark/run/perf.py).

``failure-search-<suite>-<decider>``: distinct crashes per simulated episode of the CMA-ES failure search
over the same figure for random sampling of the suite at the same budget (``search.compare``: three
search seeds, three random seeds, pooled), and the wall time of one search. The same measurement, for
more deciders, is ``scripts/failure_search_ratio.py`` (its output: docs/failure-search-ratio.md).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

ROWS = (("table1", "fuzzy"), ("table1", "ppo"), ("table1", "ppo+shield"))
BUDGET = 2000
SEEDS = (0, 1, 2)


def add_failure_search_rows(report: Any, progress: Callable[[str], None] = print) -> None:
    from overtakezoo import zoo
    from overtakezoo.benchmark.failures.search import compare
    from overtakezoo.envs.suites import load_suite

    for suite_name, decider_name in ROWS:
        rid = f"failure-search-{suite_name}-{decider_name}"
        try:
            suite = load_suite(suite_name)
            r = compare(suite, zoo.load(decider_name, suite.config), BUDGET, list(SEEDS), list(SEEDS))
        except Exception as exc:  # a missing extra (cma) or member is reported, not fatal
            progress(f"{rid}: not measured: {str(exc).splitlines()[0]}")
            continue
        found = [s["distinct"] for s in r["search"]]
        rand = [s["distinct"] for s in r["random"]]
        ratio = r["ratio"] if r["ratio"] is not None else r["ratio_at_least"]
        bound = "" if r["ratio"] is not None else " (random found none: a lower bound, rule of three)"
        report.add(
            rid,
            f"failure search on {suite_name} for {decider_name}: distinct crashes per episode, CMA-ES "
            f"search / random sampling, {BUDGET} episodes each, {len(SEEDS)} seeds each (search found "
            f"{found}, random {rand}){bound}",
            "x",
            [ratio],
            digits=1,
            search=r["search"],
            random=r["random"],
        )
        report.add(
            f"{rid}-wall",
            f"one such search ({BUDGET} episodes, {decider_name} on {suite_name}), wall time",
            "s",
            [s["wall_s"] for s in r["search"]],
            digits=2,
        )
