"""One declaration per per-scenario metric (issue 38): a metric added to benchmark/results/registry.py,
and nowhere else, is recorded by the runner, written, validated against the results schema, loaded
back, summarized, shown in the metrics table and listed in the docs' table of arrays."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from conftest import suite_file
from overtakezoo import zoo
from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.results import registry
from overtakezoo.benchmark.results.metrics import TABLE, render_table
from overtakezoo.benchmark.results.results import Results
from overtakezoo.benchmark.results.schema import PER_SCENARIO, recorded_keys, results_schema, validate
from overtakezoo.benchmark.run.runner import run_suite
from overtakezoo.envs.suites import load_suite

REPO = Path(__file__).resolve().parents[2]

# A metric the core already reports (OvertakeCore.info()["episode_steps"]) but no results file stores.
STEPS = registry.Metric(
    "steps",
    registry.CORE,
    np.int64,
    "",
    "core steps until the episode ended",
    bounds=(0, 10**9),
    key="episode_steps",
    summary=registry.Summary("steps per scenario"),
)


@pytest.fixture
def with_steps(monkeypatch):
    """The registry with STEPS declared last: the one edit adding a metric makes."""
    monkeypatch.setattr(registry, "METRICS", (*registry.METRICS, STEPS))


@pytest.fixture
def run(tmp_path, with_steps):
    suite = load_suite(suite_file(tmp_path / "tiny.toml", 6, time_limit=20.0))
    results = run_suite(suite, zoo.load("rule-fsm", suite.config), progress=False)
    return suite, results, results.save(tmp_path / "steps.json")


def test_a_declared_metric_is_recorded_from_its_source(run):
    suite, results, _ = run
    assert "steps" in results.per and list(results.per) == list(recorded_keys(1))
    steps = results.per["steps"]
    assert steps.dtype == np.int64 and steps.shape == (6,) and (steps > 0).all()
    # one core step per dt of episode time
    assert np.array_equal(steps, np.round(results.per["episode_time"] / suite.config.dt).astype(np.int64))


def test_its_file_validates_and_loads_back_the_same(run):
    _, results, path = run
    doc = json.loads(path.read_text())
    assert doc["scenarios"]["steps"] == results.per["steps"].tolist()
    schema = results_schema()
    assert schema["properties"]["scenarios"]["properties"]["steps"]["items"] == {
        "type": "integer",
        "minimum": 0,
        "maximum": 10**9,
    }
    assert "steps" in schema["properties"]["scenarios"]["required"]  # a core array: every file has it
    loaded = Results.load(path)
    assert loaded.per["steps"].dtype == np.int64 and np.array_equal(loaded.per["steps"], results.per["steps"])
    assert loaded.to_json() == path.read_text()
    doc["scenarios"]["steps"][2] = -1  # the declared bounds hold
    with pytest.raises(UserError, match=r"scenarios\.steps\.2: -1 is outside \[0, 1000000000\]"):
        validate(doc)
    del doc["scenarios"]["steps"]
    with pytest.raises(UserError, match="'steps' is a required property"):
        validate(doc)


def test_it_is_summarized_and_in_the_metrics_table(run):
    _, results, _ = run
    row = results.summary["steps"]
    assert row["value"] == pytest.approx(results.per["steps"].mean()) and row["n"] == 6
    assert list(TABLE)[-1] == ("steps", "steps per scenario", "mean", "")
    table = render_table([("rule-fsm", results.summary)])
    last = table.splitlines()[-1]
    assert last.startswith("steps per scenario ")
    assert last.endswith(f" {row['value']:.2f} [{row['lo']:.2f}, {row['hi']:.2f}]")


def test_it_is_in_the_docs_table_of_arrays(with_steps):
    pytest.importorskip("mkdocs")
    spec = importlib.util.spec_from_file_location("mkdocs_hooks_under_test", REPO / "tools" / "mkdocs_hooks.py")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    page = type("Page", (), {"file": type("File", (), {"src_uri": "metrics.md", "generated_by": None})()})()
    text = hooks.on_page_markdown((REPO / "docs" / "metrics.md").read_text(), page, None, None)
    row = next(line for line in text.splitlines() if line.startswith("| `steps` |"))
    assert "`OvertakeCore.info()['episode_steps']`" in row and "steps per scenario" in row
    assert all(f"| `{name}` |" in text for name in PER_SCENARIO)


def test_without_it_nothing_changes(tmp_path):
    """The declarations give the format the shipped files were written in: a file without the new
    array is what a run writes, and the views hold the arrays that files have always had."""
    assert "steps" not in PER_SCENARIO and "steps" not in results_schema()["properties"]["summary"]["properties"]
    assert list(recorded_keys(2, safety=False)) == [
        *("outcome", "crash_npc", "crash_lane", "completion_time", "episode_time", "aborts", "switches"),
        *("opposite_time", "min_ttc", "peak_lat_accel", "peak_jerk", "npc1_speed", "npc2_speed"),
        *("crash_av", "lead_npc"),
    ]
