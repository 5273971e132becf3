"""The one "Submit your policy" guide, ``overtakezoo.benchmark.leaderboard.guide.GUIDE``: the same text on
the leaderboard page (``leaderboards/README.md``, generated) and on the documentation site
(``guides/submit.md``, generated from it); the README's quickstart is its code (checked here), and,
slow, its code blocks run as written: the python block (SB3 DQN's defaults on
``overtakezoo/Overtake-v1``, 200k decisions) in a subprocess, then every ``overtakezoo`` line of its
bash blocks (card, eval on table1, submit, verify, regenerate) in a temporary folder holding a copy of
the repository's ``leaderboards/`` (the guide runs from a clone's root, where ``./leaderboards`` is the
board, so nothing is written into the repository's own). The policy must reach at least rule-fsm's
table1 success (0.71) at no more than its crash rate (0.29).

    python -m pytest -m slow tests/docs/test_guide_submit.py -q
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

import gymnasium
import pytest

import overtakezoo.envs  # noqa: F401 (registers the ids)
from guide_cli import RULE_FSM_TABLE1, overtakezoo
from overtakezoo.benchmark.leaderboard.guide import GUIDE, GUIDE_HEADING
from overtakezoo.envs.faces.gym import ENV_ID

REPO = Path(__file__).resolve().parents[2]
BLOCK = re.compile(r"^```(\w+)\n(.*?)^```$", re.M | re.S)


def guide_blocks() -> list[tuple[str, str]]:
    """The guide's fenced code blocks, in order: (language, body)."""
    return BLOCK.findall(GUIDE)


def guide_commands() -> list[list[str]]:
    """Every command line of the guide's bash blocks, split as a shell would (comments dropped)."""
    return [
        args
        for lang, body in guide_blocks()
        if lang == "bash"
        for args in (shlex.split(line, comments=True) for line in body.splitlines())
        if args
    ]


def option(args: list[str], name: str) -> str:
    return args[args.index(name) + 1]


def test_the_readme_quickstart_is_the_guide_and_the_leaderboard_page_shows_it():
    # README.md's "Evaluate and submit your own policy" blocks name this test: they are the guide's
    # own code (its python block verbatim, its commands), which the slow test below runs.
    from doc_blocks import run_by

    python, bash = run_by("tests/docs/test_guide_submit.py")
    assert python.body == guide_blocks()[0][1]
    readme_commands = [args for args in (shlex.split(line, comments=True) for line in bash.body.splitlines()) if args]
    assert readme_commands == guide_commands()
    page = (REPO / "leaderboards" / "README.md").read_text("utf-8")
    assert "\n" + GUIDE_HEADING + "\n\n" + GUIDE in page, "regenerate the leaderboard: overtakezoo leaderboard"


def test_the_guide_trains_on_the_training_world_cards_its_hold_then_evaluates_and_submits():
    assert [lang for lang, _ in guide_blocks()] == ["python", "bash", "bash", "bash"]
    train = guide_blocks()[0][1]
    assert f'gym.make("{ENV_ID}")' in train and 'DQN("MlpPolicy"' in train
    commands = guide_commands()
    assert all(args[0] == "overtakezoo" for args in commands), commands
    assert [args[1] for args in commands] == ["card", "eval", "submit", "leaderboard", "leaderboard"]
    card, evaluate, submit = commands[:3]
    # the card states the hold and the training suite of the env the python block trains on
    spec = gymnasium.spec(ENV_ID)
    assert int(option(card, "--action-repeat")) == spec.kwargs["hold_steps"] == 10
    assert option(card, "--suite") == spec.kwargs["suite"] == "table1-train"
    zip_file = card[2]
    assert f'model.save("{zip_file}")' in train
    assert option(evaluate, "--policy") == option(submit, "--policy") == zip_file
    assert option(evaluate, "--suite") == "table1" and submit[2] == option(evaluate, "--out")
    assert all("--root" not in args for args in commands)  # run from a clone's root: ./leaderboards


def _tree(root: Path) -> list[tuple[str, int, int]]:
    return sorted(
        (str(p.relative_to(root)), p.stat().st_size, p.stat().st_mtime_ns) for p in root.rglob("*") if p.is_file()
    )


@pytest.mark.slow
def test_the_guide_as_written_beats_rule_fsm_and_its_row_verifies(tmp_path):
    pytest.importorskip("stable_baselines3")
    pytest.importorskip("torch")
    shutil.copytree(REPO / "leaderboards", tmp_path / "leaderboards")
    assert (tmp_path / "leaderboards" / "submissions").is_dir()  # so the CLI's default root is this copy
    repo_board = _tree(REPO / "leaderboards")

    outputs: list[str] = []
    walls: list[tuple[str, float]] = []
    for i, (lang, body) in enumerate(guide_blocks()):
        if lang == "python":
            script = tmp_path / f"guide_block_{i}.py"
            script.write_text(body, "utf-8")
            start = time.perf_counter()
            done = subprocess.run(
                [sys.executable, script.name], cwd=tmp_path, capture_output=True, text=True, env=dict(os.environ)
            )
            walls.append(("python block", time.perf_counter() - start))
            assert done.returncode == 0, done.stdout + done.stderr
            continue
        for line in body.splitlines():
            args = shlex.split(line, comments=True)
            if not args:
                continue
            assert args[0] == "overtakezoo", line
            start = time.perf_counter()
            outputs.append(overtakezoo(*args[1:], cwd=tmp_path))
            walls.append((" ".join(args[:2]), time.perf_counter() - start))
    print("; ".join(f"{what} {s / 60:.1f} min" for what, s in walls))

    evaluate = next(args for args in guide_commands() if args[1] == "eval")
    summary = json.loads((tmp_path / option(evaluate, "--out")).read_text())["summary"]
    success, crash = summary["success_rate"]["value"], summary["crash_rate"]["value"]
    print(f"table1: success {success:.3f}, crash {crash:.3f} (n={summary['success_rate']['n']})")
    assert summary["success_rate"]["n"] == 3000
    assert success >= RULE_FSM_TABLE1["success_rate"], summary["success_rate"]
    assert crash <= RULE_FSM_TABLE1["crash_rate"], summary["crash_rate"]

    assert any(
        "verified submissions/table1/my-dqn.json: 3000 of 3000 scenarios reproduce exactly" in out for out in outputs
    ), outputs
    assert (tmp_path / "leaderboards" / "submissions" / "table1" / "my-dqn.json").is_file()
    assert _tree(REPO / "leaderboards") == repo_board  # the repository's board was never written
