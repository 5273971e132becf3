"""Failure search (benchmark/failures/search.py, `overtakezoo search`): real searches at small budgets."""

import json
import tomllib

import numpy as np
import pytest

pytest.importorskip("cma")

from test_benchmark_cli import one_line_error  # noqa: E402

from conftest import suite_file  # noqa: E402
from overtakezoo import zoo  # noqa: E402
from overtakezoo.benchmark.cli import main  # noqa: E402
from overtakezoo.benchmark.failures.search import Archive, cma_search, random_search  # noqa: E402
from overtakezoo.envs.suites import load_suite  # noqa: E402


@pytest.fixture(scope="module")
def rule_fsm_failures(tmp_path_factory):
    """`overtakezoo search` on table1 for rule-fsm, 256 episodes, seed 3, run twice."""
    d = tmp_path_factory.mktemp("search")
    argv = ["search", "--decider", "rule-fsm", "--suite", "table1", "--budget", "256", "--seed", "3", "--no-progress"]
    assert main([*argv, "--out", str(d / "a.toml")]) == 0
    assert main([*argv, "--out", str(d / "b.toml")]) == 0
    return d


def test_the_same_seed_writes_the_same_bytes(rule_fsm_failures):
    assert (rule_fsm_failures / "a.toml").read_bytes() == (rule_fsm_failures / "b.toml").read_bytes()


def test_the_torch_core_finds_the_same_failures(rule_fsm_failures):
    """`--backend torch` (the GPU path, on the CPU) writes the numpy search's file byte for byte."""
    pytest.importorskip("torch")
    out = rule_fsm_failures / "torch.toml"
    argv = ["search", "--decider", "rule-fsm", "--suite", "table1", "--budget", "256", "--seed", "3", "--no-progress"]
    assert main([*argv, "--backend", "torch", "--out", str(out)]) == 0
    assert out.read_bytes() == (rule_fsm_failures / "a.toml").read_bytes()


def test_found_failures_crash_again_in_eval(rule_fsm_failures, capsys):
    path = rule_fsm_failures / "a.toml"
    doc = tomllib.loads(path.read_text())
    assert doc["count"] == len(doc["scenarios"]) > 20
    assert {s["found"]["kind"] for s in doc["scenarios"]} == {"crash"}
    assert doc["search"]["suite_hash"] == load_suite("table1").hash and doc["search"]["episodes"] == 256
    out = rule_fsm_failures / "r.json"
    assert main(["eval", "--suite", str(path), "--decider", "rule-fsm", "--out", str(out), "--no-progress"]) == 0
    res = json.loads(out.read_text())
    outcome = res["scenarios"]["outcome"]
    assert len(outcome) == doc["count"] and set(outcome) == {2}  # every listed scenario crashes again
    # ... and the crash times are the ones the search saw
    assert np.allclose(res["scenarios"]["episode_time"], [s["found"]["t"] for s in doc["scenarios"]])
    # Another decider drives the same file (the failures are a suite like any).
    assert main(["eval", "--suite", str(path), "--decider", "always-follow", "--out", str(out), "--no-progress"]) == 0
    assert set(json.loads(out.read_text())["scenarios"]["outcome"]) == {3}


def test_search_beats_random_on_a_rare_failure():
    # fuzzy crashes in ~0.1 % of table1; 768 episodes of CMA-ES find distinct crashes where random
    # sampling of the same budget finds (almost) none.
    suite = load_suite("table1")
    d = zoo.load("fuzzy", suite.config)
    found = cma_search(suite, d, 768, seed=1, progress=False)
    rand = random_search(suite, d, 768, seed=1, progress=False)
    assert found.distinct >= 3 and found.distinct > 2 * max(rand.distinct, 1), (found.distinct, rand.distinct)
    assert found.episodes == rand.episodes == 768
    # distinct failures are more than 5 % of a range apart
    u = found.units
    assert (np.abs(u[:, None] - u[None]).max(axis=2) + np.eye(len(u))).min() > 0.05


def test_archive_counts_near_points_once():
    a = Archive(2, 0.1)
    added = a.add(np.array([[0.5, 0.5], [0.55, 0.5], [0.8, 0.5], [0.5, 0.5]]))
    assert added.tolist() == [True, False, True, False] and len(a.points) == 2
    assert a.add(np.array([[0.5, 0.62]])).tolist() == [True]


def test_nothing_found_writes_nothing(tmp_path, capsys):
    out = tmp_path / "f.toml"
    assert (
        main(
            [
                "search",
                "--decider",
                "always-follow",
                "--suite",
                "table1",
                "--budget",
                "64",
                "--out",
                str(out),
                "--no-progress",
            ]
        )
        == 1
    )
    assert not out.exists() and "nothing written" in capsys.readouterr().err


def test_rss_target_and_params(tmp_path, capsys):
    out = tmp_path / "f.toml"
    assert (
        main(
            [
                "search",
                "--decider",
                "fuzzy",
                "--suite",
                "table1",
                "--budget",
                "128",
                "--target",
                "rss",
                "--param",
                "oncoming_gap=20:80",
                "--param",
                "sensor_range=30:60",
                "--out",
                str(out),
                "--no-progress",
            ]
        )
        == 0
    )
    suite = load_suite(out)
    doc = tomllib.loads(out.read_text())
    assert doc["search"]["parameters"] == ["oncoming_gap", "sensor_range"]
    assert {s["found"]["kind"] for s in doc["scenarios"]} <= {"crash", "rss"}
    assert all(30 <= s["sensor_range"] <= 60 and 20 <= s["oncoming_gap"] <= 80 for s in doc["scenarios"])
    assert suite.distribution.oncoming_gap == (20.0, 80.0)


def fixed_suite(tmp_path):
    fixed = {
        "lead_speed": [2.0, 2.0],
        "oncoming_speed": [2.0, 2.0],
        "lead_gap": [9.0, 9.0],
        "oncoming_gap": [60.0, 60.0],
    }
    return suite_file(tmp_path / "fixed.toml", 3000, **fixed)


@pytest.mark.parametrize(
    "extra, needle",
    [
        (["--budget", "0"], "--budget 0: expected a positive number of episodes"),
        (["--budget", "-5"], "--budget -5: expected a positive number"),
        (["--budget", ""], "--budget '': expected a positive number"),
        (["--budget", "many"], "--budget 'many': expected a positive number"),
        (["--param", "lead_sped"], "--param lead_sped: unknown parameter for suite 'table1'"),
        (["--param", "ego_speed"], "is a single value"),
        (["--decider", "nobody"], "nobody"),
        (["--out", "/proc/nope/f.toml"], "cannot write /proc/nope/f.toml"),
        (["--suite", "nosuch"], "unknown suite 'nosuch'"),
        (["--distinct", "1.5"], "--distinct 1.5"),
        (["--name", "Bad Name"], "--name 'Bad Name'"),
        (["--ttc", "-1"], "--ttc -1.0"),
    ],
)
def test_bad_input_is_one_error_line(tmp_path, capsys, extra, needle):
    argv = {"--decider": "rule-fsm", "--suite": "table1", "--budget": "64", "--out": str(tmp_path / "f.toml")}
    rest = []
    for i in range(0, len(extra), 2):
        if extra[i] in argv:
            argv[extra[i]] = extra[i + 1]
        else:
            rest += extra[i : i + 2]
    err = one_line_error(capsys, ["search", *[x for kv in argv.items() for x in kv], *rest, "--no-progress"])
    assert needle in err, err
    assert not (tmp_path / "f.toml").exists()


def test_a_suite_with_no_range_is_one_error(tmp_path, capsys):
    err = one_line_error(
        capsys,
        [
            "search",
            "--decider",
            "rule-fsm",
            "--suite",
            str(fixed_suite(tmp_path)),
            "--budget",
            "10",
            "--out",
            str(tmp_path / "f.toml"),
        ],
    )
    assert "has no searchable range" in err


@pytest.mark.parametrize("command", ["search", "export-xosc", "failure-board"])
def test_help_has_examples(capsys, command):
    with pytest.raises(SystemExit) as exc:
        main([command, "--help"])
    assert exc.value.code == 0 and "examples:" in capsys.readouterr().out


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["--budget", "0"], "--budget 0"),
        (["--jobs", "0"], "--jobs 0"),
        (["--deciders", "rule-fsm,nobody"], "unknown decider 'nobody'"),
        (["--deciders", "rule-fsm,rule-fsm"], "expected distinct zoo names"),
        (["--out", "/proc/nope/b"], "cannot write /proc/nope"),
    ],
)
def test_failure_board_bad_input(tmp_path, capsys, argv, needle):
    err = one_line_error(capsys, ["failure-board", "--out", str(tmp_path / "b"), *argv])
    assert needle in err and not (tmp_path / "b").exists()


def test_perf_rows(monkeypatch):
    from overtakezoo.benchmark.failures import perf_rows
    from overtakezoo.benchmark.run.perf import Report

    monkeypatch.setattr(perf_rows, "ROWS", (("table1", "rule-fsm"),))
    monkeypatch.setattr(perf_rows, "BUDGET", 32)
    monkeypatch.setattr(perf_rows, "SEEDS", (0,))
    report = Report(lambda line: None)
    perf_rows.add_failure_search_rows(report)
    row = report.get("failure-search-table1-rule-fsm")
    assert row["unit"] == "x" and row["median"] > 0 and row["search"][0]["episodes"] == 32
    assert report.get("failure-search-table1-rule-fsm-wall")["median"] > 0
