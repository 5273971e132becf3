"""The OvertakeZoo score and the Table I side-by-side: pure functions of outcome counts."""

import json
from pathlib import Path

import pytest

from overtakezoo.benchmark.leaderboard import headline, paper_table
from overtakezoo.benchmark.leaderboard.headline import Counts, score
from overtakezoo.benchmark.suite_groups import CORE

REFERENCE = Path(__file__).resolve().parents[2] / "leaderboards" / "reference" / "paper.json"


def table(success, crash, n=1000):
    return [Counts(success, crash, n)]


def test_never_overtaking_scores_zero_and_a_table1_specialist_cannot_top_the_board():
    follow = {s: table(0, 0) for s in CORE}
    specialist = {s: table(1000, 0) if s == "table1" else table(100, 400) for s in CORE}
    steady = {s: table(700, 20) for s in CORE}
    assert score(follow)["value"] == 0.0
    assert score(specialist)["value"] < 0 < score(steady)["value"]
    md = headline.render({"specialist": specialist, "steady": steady, "oracle": steady}, {"oracle"})
    rows = [line for line in md.splitlines() if line.startswith("| ")][1:]
    assert rows[0].startswith("| 1 | steady") and rows[1].startswith("| 2 | specialist")
    assert rows[2].startswith("| upper bound | oracle (privileged)")


def test_score_ci_brackets_the_value_is_seeded_and_widens_with_seed_spread():
    same = {s: [Counts(800, 50, 1000)] * 3 for s in CORE}
    spread = {s: [Counts(600, 50, 1000), Counts(800, 50, 1000), Counts(1000, 0, 1000)] for s in CORE}
    a, b = score(same), score(same)
    assert a == b and a["lo"] <= a["value"] <= a["hi"] and a["seeds"] == 3
    c = score(spread)
    assert c["hi"] - c["lo"] > 3 * (a["hi"] - a["lo"])
    assert score({"table1": table(1, 0)})["missing"]  # a decider missing suites gets no score
    with pytest.raises(ValueError, match="same number of seeds"):
        score({s: same[s] if s != "dense" else table(1, 0) for s in CORE})


def test_mean_over_seeds_reports_each_seed():
    m = headline.mean_over_seeds([Counts(900, 10, 1000), Counts(950, 5, 1000), Counts(920, 8, 1000)], "success")
    assert m["per_seed"] == [0.9, 0.95, 0.92] and m["lo"] < m["value"] < m["hi"]


def test_paper_table_verdicts_follow_the_cis():
    ref = json.loads(REFERENCE.read_text())

    def rate(v, lo, hi):
        return {"value": v, "lo": lo, "hi": hi}

    dqn = {
        "success_rate": rate(0.95, 0.94, 0.96),
        "crash_share_npc1": rate(0.1, 0.05, 0.2),
        "crash_share_npc2": rate(0.9, 0.8, 0.95),
    }
    fsm = {
        "success_rate": rate(0.7, 0.68, 0.72),
        "crash_share_npc1": rate(0.1, 0.07, 0.12),
        "crash_share_npc2": rate(0.9, 0.88, 0.93),
    }
    v = paper_table.verdicts(ref["rows"][0], ref["rows"][1], dqn, fsm)
    assert v["success_rate"] == ("above", "above")  # the paper's shape holds
    assert v["crash_share_npc1"] == ("above", "level")  # overlapping CIs: level, the shape differs
    notes = {
        "success_rate": {"shape": "holds", "text": "WHY-HOLDS"},
        "crash_share_npc1": {"shape": "holds", "text": "STALE"},
    }
    md = paper_table.render(ref, dqn, fsm, None, notes)
    assert "WHY-HOLDS" in md and "STALE" not in md  # a note whose verdict no longer matches is not shown
    assert md.count("\n| ") == 7  # 7 Table I rows after the header
