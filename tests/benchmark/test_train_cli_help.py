"""What a user reads first: the README's first command installs only what it runs (no torch), `train`
without torch is one `error:` line naming the extra, and `train --help` names every member that
trains, the suites the zoo trained on and the files a run writes."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import suite_file
from overtakezoo import zoo
from overtakezoo.benchmark.cli import main
from overtakezoo.zoo.train.contract import TRAINERS, run_files

ROOT = Path(__file__).resolve().parents[2]


def test_readme_first_command_is_the_base_install_and_ci_runs_the_second():
    lines = ROOT.joinpath("README.md").read_text().split("```bash\n", 1)[1].splitlines()
    assert lines[0] == "pip install -e . && overtakezoo eval --suite table1 --decider rule-fsm"
    assert lines[1] == "pip install -e '.[test]' && python -m pytest -n 2 && python -m pytest -m board"
    assert lines[1] in ROOT.joinpath(".ci", "run").read_text().splitlines()
    base = __import__("tomllib").loads(ROOT.joinpath("pyproject.toml").read_text())["project"]["dependencies"]
    assert not [d for d in base if re.match(r"(torch|rsl-rl|minari)\b", d)]  # eval needs numpy only


def test_eval_never_imports_torch(tmp_path):
    code = (
        "import sys; sys.modules['torch'] = None; from overtakezoo.benchmark.cli import main; "
        "sys.exit(main(['eval', '--suite', sys.argv[1], '--decider', 'dqn', '--out', sys.argv[2], '--no-progress']))"
    )
    tiny = suite_file(tmp_path / "tiny.toml", 20)
    done = subprocess.run(
        [sys.executable, "-c", code, str(tiny), str(tmp_path / "dqn.json")], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "dqn.json").is_file()


@pytest.mark.parametrize("member", zoo.names("learned"))
def test_train_without_torch_is_one_error_line_naming_the_extra(tmp_path, member):
    argv = ["train", member, "--out", str(tmp_path / "run"), "--no-progress"]
    if member in ("bc", "cql"):
        argv += ["--dataset", "overtakezoo/table1/rule-fsm-v0"]
    code = (
        f"import sys; sys.modules['torch'] = None; from overtakezoo.benchmark.cli import main; sys.exit(main({argv!r}))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr == f"error: training {member} needs torch (pip install -e '.[train]')\n"


def test_train_help_names_the_members_the_zoos_suites_and_the_files(capsys):
    with pytest.raises(SystemExit):
        main(["train", "--help"])
    text = " ".join(capsys.readouterr().out.split())  # argparse wraps lines
    learned = zoo.names("learned")
    assert f"Train a learned member ({', '.join(learned)})" in text
    assert "dqn, ppo on core-train; ps-dqn on core-train+multi-train" in text  # the shipped cards say so
    for name in learned:
        files = run_files(zoo.member(name).trainer, "<member>")
        assert f": {', '.join(files)}" in text
    # The trainers with a name of their own (not members): named, described and their files listed.
    for name, (module, what) in TRAINERS.items():
        assert name not in learned and f"or a trainer of its own ({name}: {what})" in text
        assert f"{name}: {', '.join(run_files(module, '<member>'))}" in text
    assert "<member>-<eval suite>.results.json" in text and "pip install -e '.[train]'" in text


def test_train_help_lists_exactly_the_files_a_dqn_run_writes(tmp_path, capsys):
    pytest.importorskip("torch")
    suite = suite_file(tmp_path / "tiny.toml", 4)
    out = tmp_path / "run"
    assert (
        main(
            [
                "train",
                "dqn",
                "--steps",
                "600",
                "--seed",
                "0",
                "--out",
                str(out),
                "--eval-suite",
                str(suite),
                "--no-progress",
                "--set",
                "learning_starts=100",
                "--set",
                "num_envs=16",
            ]
        )
        == 0
    )
    capsys.readouterr()
    written = sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file())
    assert written == sorted([*run_files("dqn", "dqn"), "dqn-tiny.results.json"])
    assert json.loads((out / "dqn.json").read_text())["results"]["tiny"]["count"] == 4
