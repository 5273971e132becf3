"""The leaderboard's safety pages: a Safety table per suite (rows recorded before the safety metrics
say so), the shielded rows beside their plain deciders, the index's shield section and plot, and the
score page's RSS column."""

from __future__ import annotations

import numpy as np
from test_benchmark_runner import small_suite

from overtakezoo import zoo
from overtakezoo.benchmark.leaderboard import safety_board
from overtakezoo.benchmark.leaderboard.rows import Row
from overtakezoo.benchmark.results.results import SAFETY_PER_SCENARIO, Results
from overtakezoo.benchmark.run.runner import run_suite
from overtakezoo.benchmark.suite_groups import CORE


def rows(tmp_path, names, count=40):
    suite = small_suite(tmp_path, count=count)
    return [
        Row(f"submissions/small/{n}.json", run_suite(suite, zoo.load(n, suite.config), progress=False)) for n in names
    ]


def without_safety(row: Row) -> Row:
    r = row.results
    per = {k: v for k, v in r.per.items() if k not in SAFETY_PER_SCENARIO}
    from overtakezoo.benchmark.results.results import summary_of

    meta = {**r.meta, "decider": {**r.meta["decider"], "name": "recorded-before"}}
    return Row(row.rel.replace(".json", "-old.json"), Results(meta, per, summary_of(per, r.meta["seed"]), r.timing))


def test_safety_table_shows_the_rss_violations_and_old_rows_as_not_measured(tmp_path):
    fsm, shielded = rows(tmp_path, ["rule-fsm", "rule-fsm+shield"])
    lines = safety_board.safety_section([fsm, shielded, without_safety(fsm)])
    table = [ln for ln in lines if ln.startswith("| ")]
    assert table[0].startswith("| name | RSS (opposite direction) violated")
    by_name = {ln.split(" | ")[0][2:]: ln for ln in table[1:]}
    rate = lambda r: 100 * r.results.summary["rss_violation_rate"]["value"]  # noqa: E731
    assert f"{rate(fsm):.1f} %" in by_name["rule-fsm"] and f"{rate(shielded):.1f} %" in by_name["rule-fsm+shield"]
    assert rate(shielded) < rate(fsm)  # the shield keeps the RSS distance rule-fsm breaks
    assert "not measured" in by_name["recorded-before"] and "not measured" not in by_name["rule-fsm"]


def test_shield_section_pairs_each_shielded_row_with_its_decider(tmp_path):
    fsm, shielded, fuzzy = rows(tmp_path, ["rule-fsm", "rule-fsm+shield", "fuzzy"], count=20)
    assert safety_board.shield_pairs([fsm, shielded, fuzzy]) == [(fsm, shielded)]
    text = "\n".join(safety_board.shield_section([fuzzy, shielded, fsm]))
    assert "| rule-fsm | " in text and "fuzzy" not in text.split("|---|")[-1]
    assert safety_board.shield_section([fuzzy]) == []


def test_index_section_and_plot_over_the_core_suites(tmp_path):
    fsm, shielded = rows(tmp_path, ["rule-fsm", "rule-fsm+shield"], count=20)
    live = {s: [fsm, shielded] for s in CORE}
    means = safety_board.core_means(live, CORE)
    assert set(means) == {"rule-fsm", "rule-fsm+shield"}
    assert np.isclose(means["rule-fsm"]["crash"], fsm.results.summary["crash_rate"]["value"])
    lines, png = safety_board.readme_section(means, CORE)
    assert png[:4] == b"\x89PNG" and "| rule-fsm | " in "\n".join(lines)
    column = safety_board.safety_column(means)
    assert column["rule-fsm"] == f"{100 * fsm.results.summary['rss_violation_rate']['value']:.1f}"
    # A suite missing the pair: no section, no plot.
    assert safety_board.readme_section(safety_board.core_means({"table1": [fsm]}, CORE), CORE) == ([], None)
