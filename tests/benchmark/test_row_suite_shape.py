"""Rows are checked against the current suite file, not against themselves (issue 35): a row that keeps
its real per-scenario values and appends fabricated successes (suite.count and range raised, summary
recomputed), or drops its safety arrays, reproduced "1000 of 1000 scenarios" while the board showed
its own numbers. `submit` and `leaderboard --verify` refuse it; the board shows it with no numbers."""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import last_error_line
from overtakezoo import zoo
from overtakezoo.benchmark.cli import main
from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.leaderboard.generate import generate
from overtakezoo.benchmark.leaderboard.rows import suite_mismatch
from overtakezoo.benchmark.leaderboard.submission import submit
from overtakezoo.benchmark.leaderboard.verify import verify
from overtakezoo.benchmark.results.results import Results, summary_of
from overtakezoo.benchmark.results.schema import SAFETY_PER_SCENARIO, recorded_keys
from overtakezoo.benchmark.run.runner import run_suite
from overtakezoo.envs import SUCCESS
from overtakezoo.envs.suites import load_suite

NAME = "always-overtake"


@pytest.fixture
def honest(tiny):
    """A built-in member's results on the 12-scenario suite, as `eval` writes them."""
    suite = load_suite(tiny)
    return run_suite(suite, zoo.load(NAME, suite.config), progress=False)


def padded(r: Results, extra: int) -> Results:
    """``r``'s real values with ``extra`` fabricated successes appended, suite.count and range raised
    to match and the summary recomputed: a file consistent in itself."""
    n = r.suite["count"] + extra
    per = {k: np.concatenate([v, np.repeat(v[:1], extra)]) for k, v in r.per.items()}
    per["outcome"][-extra:] = SUCCESS
    meta = {**r.meta, "suite": {**r.suite, "count": n}, "range": [0, n]}
    return Results(meta, per, summary_of(per, meta["seed"]), r.timing)


def without_safety(r: Results) -> Results:
    per = {k: v for k, v in r.per.items() if k not in SAFETY_PER_SCENARIO}
    return Results(r.meta, per, summary_of(per, r.meta["seed"]), r.timing)


def resuited(r: Results, **suite) -> Results:
    return Results({**r.meta, "suite": {**r.suite, **suite}}, r.per, r.summary, r.timing)


def test_the_required_arrays_are_what_a_run_records(honest, tiny):
    assert list(honest.per) == list(recorded_keys(1))  # one list, read by the runner and by the rows check
    assert suite_mismatch(honest, load_suite(tiny)) == []


@pytest.mark.parametrize(
    "forge, field, says",
    [
        (lambda r: padded(r, 4), "suite.count", "a suite block with count 16 (the suite file gives 12)"),
        (without_safety, "scenarios.rss_violation_share", "a run without scenarios.rss_violation_share"),
        (lambda r: resuited(r, version=r.suite["version"] + 1), "suite.version", "the suite file gives"),
    ],
    ids=["appended-scenarios", "dropped-safety-arrays", "other-suite-version"],
)
def test_submit_refuses_a_row_without_the_suites_shape(honest, tiny, tmp_path, capsys, forge, field, says):
    forged = tmp_path / "forged.json"
    forge(honest).save(forged)
    Results.load(forged)  # consistent in itself: it loads
    err = last_error_line(capsys, ["submit", str(forged), "--root", str(tmp_path / "lb")])
    assert err.startswith(f"error: {forged}: {field}: measured on ") and says in err, err
    assert "not what a run of the current suite file gives" in err
    assert not (tmp_path / "lb" / "submissions" / tiny).exists()


def test_submit_refuses_a_summary_that_is_not_its_arrays(honest, tmp_path):
    summary = json.loads(json.dumps(honest.summary))
    summary["success_rate"]["value"] = 0.996
    with pytest.raises(UserError, match="summary: does not match the per-scenario arrays"):
        submit(Results(honest.meta, honest.per, summary, honest.timing), tmp_path / "lb")
    assert main(["submit", str(honest.save(tmp_path / "r.json")), "--root", str(tmp_path / "lb")]) == 0


@pytest.mark.parametrize(
    "forge, field",
    [(lambda r: padded(r, 4), "suite.count"), (without_safety, "scenarios.rss_violation_share")],
    ids=["appended-scenarios", "dropped-safety-arrays"],
)
def test_a_planted_row_is_refused_by_verify_and_shows_no_numbers(honest, tiny, tmp_path, capsys, forge, field):
    root = tmp_path / "lb"
    row = submit(honest, root)
    assert main(["leaderboard", "--root", str(root), "--verify"]) == 0
    assert "12 of 12 scenarios reproduce exactly" in capsys.readouterr().out
    filed = Results.load(row)
    forged = forge(filed)
    forged.save(row)  # what a pull request writes (its submission block kept)

    err = last_error_line(capsys, ["leaderboard", "--root", str(root), "--verify"])
    assert err.startswith(f"error: submissions/{tiny}/{NAME}.json: {field}: measured on "), err
    with pytest.raises(UserError, match=f"{field}: measured on "):  # an unchanged row, sampled: refused as well
        verify(root, sample=2, seed=0, changed=set(), log=lambda line: None)

    # The board lists it by name only, as a stale row: none of its numbers reach a page.
    files = generate(root)
    entry = json.loads(files["index.json"])["suites"][tiny]
    assert entry["entries"] == [] and entry["upper_bounds"] == []
    assert entry["stale"][0]["file"] == f"submissions/{tiny}/{NAME}.json"
    assert entry["stale"][0]["reasons"][0]["field"] == field
    page = files[f"{tiny}.md"].decode()
    ranked, apart = page.split("## Stale submissions")
    assert f"[{NAME}]" not in ranked and f"[{NAME}](submissions/{tiny}/{NAME}.json): measured on " in apart
    rate = forged.summary["success_rate"]["value"]
    assert f"{rate * 100:.1f} %" not in page
