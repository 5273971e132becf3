"""`overtakezoo perf`: every figure is measured, named by a stable id and written with its range."""

import json
from pathlib import Path

import pytest
from test_benchmark_cli import one_line_error, small_suite_file

from overtakezoo.benchmark.cli import main
from overtakezoo.benchmark.run.perf import eval_process_times, highway_version


def test_perf_writes_every_figure_with_median_and_range(tmp_path, capsys):
    out = tmp_path / "perf"
    assert (
        main(
            [
                "perf",
                "--sizes",
                "1",
                "4",
                "--seconds",
                "0.05",
                "--repeats",
                "2",
                "--batch",
                "2",
                "--no-suites",
                "--no-training",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    report = json.loads((tmp_path / "perf.json").read_text())
    markdown = (tmp_path / "perf.md").read_text()
    ids = [row["id"] for row in report["figures"]]
    expected = ["core-1", "core-4", "pettingzoo-1", "gym-1", "gym-vec-2"]
    if highway_version():  # the [compare] extra: one env against one env, a batch of 2 against 2
        expected += [
            "highway-1",
            "highway-vec-sync-2",
            "highway-vec-async-2",
            "ratio-1",
            "ratio-vec-sync-2",
            "ratio-vec-async-2",
        ]
    assert ids == expected
    for row in report["figures"]:
        assert f"| `{row['id']}` |" in markdown
        if "of" in row:
            assert set(row["of"]) <= set(ids) and row["median"] > 0
        else:
            assert len(row["runs"]) == 2 and row["min"] <= row["median"] <= row["max"] and row["min"] > 0
    assert report["machine"]["numpy"] and report["repeats"] == 2
    assert "Load average" in markdown and report["load_average_at_start"] is not None


def test_eval_process_time_is_a_whole_process_run(tmp_path):
    times = eval_process_times(str(small_suite_file(tmp_path, count=4)), "always-follow", runs=2)
    assert len(times) == 2 and all(t > 0.2 for t in times)  # interpreter start-up and imports included


def test_perf_rejects_bad_sizes(capsys):
    assert "--sizes" in one_line_error(capsys, ["perf", "--sizes", "0"])
    assert "--repeats" in one_line_error(capsys, ["perf", "--repeats", "0"])


@pytest.mark.slow
def test_training_rows_time_whole_processes_to_the_paper_level(tmp_path, monkeypatch):
    """The training rows at a toy scale, both trainers: one throughput process, one seed at one
    budget (real `overtakezoo train` and `overtakezoo eval` processes)."""
    from overtakezoo.benchmark.run import perf_training

    monkeypatch.setattr(perf_training, "SEEDS", (0,))
    monkeypatch.setattr(perf_training, "FAST_LADDER", (8,))
    monkeypatch.setattr(perf_training, "RSL_LADDER", (1,))
    monkeypatch.setattr(perf_training, "FAST_THROUGHPUT_ITERATIONS", 1)
    monkeypatch.setattr(perf_training, "FAST_THROUGHPUT_ENVS", 512)
    monkeypatch.setattr(perf_training, "THROUGHPUT_ITERATIONS", 1)
    monkeypatch.setattr(perf_training, "ZOO_LADDER", (1,))
    monkeypatch.setattr(perf_training, "HELD_BACK", 950)
    out = tmp_path / "perf"
    assert main(["perf", "--only-training", "--repeats", "1", "--out", str(out)]) == 0
    report = json.loads((tmp_path / "perf.json").read_text())
    rows = {row["id"]: row for row in report["figures"]}
    assert list(rows) == [
        f"{r}{s}"
        for r in (
            "train-throughput-core-train",
            "train-throughput-core-train-rsl-rl",
            "time-to-paper-level",
            "time-to-paper-level-rsl-rl",
        )
        for s in (("", "-wall") if "throughput" in r else ("", "-cpu", "-with-eval"))
    ] + ["time-to-zoo-quality", "time-to-zoo-quality-wall"]
    assert rows["train-throughput-core-train"]["median"] > 1000  # env-steps per CPU second
    ttp = rows["time-to-paper-level"]
    # seed 0 of the numpy PPO gets there in 8 iterations (a whole process: imports, training, outputs)
    assert 0.5 < ttp["median"] < 60 and "seed 0: 8 iterations" in ttp["what"]
    assert rows["time-to-paper-level-with-eval"]["median"] > ttp["median"]
    assert "seed 0:" in rows["time-to-paper-level-rsl-rl"]["what"]
    assert "`time-to-paper-level`" in (tmp_path / "perf.md").read_text()
    # one iteration (16k decisions) on core-train stays below the shipped ppo: the row says so, it does not pass
    zoo_row = rows["time-to-zoo-quality"]
    assert (
        "seed 0: not within 1 iterations" in zoo_row["what"]
        and "held-back training scenarios 950-999" in zoo_row["what"]
    )
    # the yardstick is the member as the leaderboard runs it: the new run is scored with the shipped
    # card's rate and threshold
    card = json.loads((Path(perf_training.__file__).parents[2] / "zoo/pretrained/ppo.json").read_text())
    assert f"decision every {card['decide_every']} core steps" in zoo_row["what"]
    assert f"{card['overtake_offset']:+g} on the OVERTAKE score" in zoo_row["what"]


def test_perf_device_rows_put_the_torch_core_beside_numpy(tmp_path, capsys):
    """`perf --backend torch` (the GPU rows' code, on the CPU): each N's numpy row beside the torch
    core in float64 and float32, and the aten operations one sync-free step dispatches."""
    pytest.importorskip("torch")
    out = tmp_path / "perf-gpu"
    argv = ["perf", "--backend", "torch", "--sizes", "16", "64", "--seconds", "0.05", "--repeats", "2"]
    assert main([*argv, "--out", str(out)]) == 0
    report = json.loads((tmp_path / "perf-gpu.json").read_text())
    ids = [row["id"] for row in report["figures"]]
    assert ids == [
        "core-16",
        "core-torch-f64-16",
        "core-torch-f32-16",
        "core-64",
        "core-torch-f64-64",
        "core-torch-f32-64",
        "ops-per-step",
    ]
    assert all(row["median"] > 0 for row in report["figures"])
    assert report["device"]["device"] == "cpu" and report["device"]["torch"]
    markdown = (tmp_path / "perf-gpu.md").read_text()
    assert markdown.startswith("# Performance report on cpu") and "Device rows: torch" in markdown
    assert "--compile: only with" in one_line_error(capsys, ["perf", "--compile"])
