"""The benchmark CLI: bad input is one line and exit 2 with nothing written; help has examples."""

import json

import pytest

from conftest import suite_file
from overtakezoo.benchmark.cli import main

COMMANDS = ["suites", "eval", "compare", "submit", "leaderboard", "decision-map"]


def small_suite_file(tmp_path, count=20, name="small", lead_gap="[8.0, 25.0]"):
    path = suite_file(tmp_path / f"{name}.toml", count, lead_gap=json.loads(lead_gap))
    return path


def one_line_error(capsys, argv):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err, err
    return err


@pytest.mark.parametrize("command", COMMANDS)
def test_help_has_examples(capsys, command):
    with pytest.raises(SystemExit) as exc:
        main([command, "--help"])
    assert exc.value.code == 0
    assert "examples:" in capsys.readouterr().out


def test_suites_lists_counts_and_hashes(capsys):
    assert main(["suites"]) == 0
    out = capsys.readouterr().out
    assert "table1 " in out and "3000" in out and "urban-50" in out


def test_eval_bad_inputs(tmp_path, capsys):
    out = tmp_path / "r.json"
    assert "unknown suite 'nope'" in one_line_error(
        capsys, ["eval", "--suite", "nope", "--decider", "always-follow", "--out", str(out)]
    )
    assert "unknown decider 'nope'" in one_line_error(
        capsys, ["eval", "--suite", "table1", "--decider", "nope", "--out", str(out)]
    )
    bad = tmp_path / "bad.toml"
    bad.write_text("name = [")
    assert "malformed TOML" in one_line_error(capsys, ["eval", "--suite", str(bad), "--decider", "always-follow"])
    assert "shard" in one_line_error(
        capsys, ["eval", "--suite", "table1", "--decider", "always-follow", "--shard", "3/3", "--out", str(out)]
    )
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert "cannot write" in one_line_error(
        capsys,
        [
            "eval",
            "--suite",
            str(small_suite_file(tmp_path)),
            "--decider",
            "always-follow",
            "--out",
            str(blocker / "r.json"),
        ],
    )
    assert not out.exists()


def test_eval_twice_byte_identical_apart_from_timing_and_compare(tmp_path, capsys):
    suite = small_suite_file(tmp_path)
    outs = [tmp_path / f"r{i}.json" for i in range(2)]
    for out in outs:
        assert (
            main(["eval", "--suite", str(suite), "--decider", "always-overtake", "--out", str(out), "--no-progress"])
            == 0
        )
    table = capsys.readouterr().out
    assert "successful overtaking" in table and "wrote" in table
    texts = [o.read_text() for o in outs]
    strip = [json.loads(t) for t in texts]
    for d in strip:
        d.pop("timing")
    assert strip[0] == strip[1]
    # Only the timing field differs, and it is a single block of the file.
    diff = [a for a, b in zip(texts[0].splitlines(), texts[1].splitlines(), strict=False) if a != b]
    assert all(any(k in line for k in ("wall_time_s", "started", "steps")) for line in diff)
    assert main(["compare", str(outs[0]), str(outs[1])]) == 0
    assert "crash in the same scenarios" in capsys.readouterr().out
    # Results from another version of the suite file are refused.
    (tmp_path / "v2").mkdir()
    other = small_suite_file(tmp_path / "v2", lead_gap="[8.0, 24.0]")
    o3 = tmp_path / "r3.json"
    assert main(["eval", "--suite", str(other), "--decider", "always-follow", "--out", str(o3), "--no-progress"]) == 0
    capsys.readouterr()
    assert "suite.hash" in one_line_error(capsys, ["compare", str(outs[0]), str(o3)])
    # A custom suite cannot go on the leaderboard.
    assert "not a built-in suite" in one_line_error(capsys, ["submit", str(outs[0]), "--root", str(tmp_path / "lb")])
    assert not (tmp_path / "lb").exists()


def test_compare_and_submit_reject_bad_files(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text('{"schema": "overtakezoo-results/1"}')
    assert "bad.json: (top level)" in one_line_error(capsys, ["compare", str(bad), str(bad)])
    assert "cannot read" in one_line_error(capsys, ["submit", str(tmp_path / "missing.json")])


def test_decision_map_writes_png(tmp_path, capsys):
    out = tmp_path / "map.png"
    assert main(["decision-map", "--decider", "always-overtake", "--out", str(out), "--resolution", "6"]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "follow 0, overtake 36, abort 0 of 36" in capsys.readouterr().out
    assert "resolution" in one_line_error(capsys, ["decision-map", "--decider", "always-follow", "--resolution", "1"])
    assert "unknown decider" in one_line_error(capsys, ["decision-map", "--decider", "nope"])
