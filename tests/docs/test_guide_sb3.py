"""The guide docs/guides/sb3.md as written (its code block names this test): train SB3 DQN on table1-train with
examples/sb3_dqn.py (torch at one thread), evaluate the zip on table1 through its policy card, and
reach at least rule-fsm's table1 success (0.71) at no more than its crash rate (0.29); then submit it
into a fresh leaderboard folder and verify the row re-runs. Seed 0; SB3 on CPU at one torch thread is
deterministic for a fixed seed on one machine (not promised across torch versions or CPUs).

    python -m pytest -m slow tests/docs/test_guide_sb3.py -q
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from guide_cli import RULE_FSM_TABLE1, overtakezoo

pytest.importorskip("stable_baselines3")
pytest.importorskip("torch")

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "examples" / "sb3_dqn.py"
STEPS, SEED = 60_000, 0  # the guide's command (docs/guides/sb3.md)


def test_sb3_guide_trains_past_rule_fsm_then_submits_and_verifies(tmp_path):
    env = dict(os.environ, OMP_NUM_THREADS="1")
    done = subprocess.run(
        [sys.executable, str(EXAMPLE), "--steps", str(STEPS), "--seed", str(SEED), "--out", "."],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        env=env,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    print(done.stdout.strip())
    card = json.loads((tmp_path / "model.card.json").read_text())
    assert card["action_repeat"] == 10 and card["suite"] == "table1-train"
    train = json.loads((tmp_path / "train.json").read_text())
    assert train["threads"] == 1 and train["train_wall_s"] <= 15 * 60, train

    overtakezoo(
        "eval", "--suite", "table1", "--policy", "model.zip", "--out", "table1.json", "--no-progress", cwd=tmp_path
    )
    summary = json.loads((tmp_path / "table1.json").read_text())["summary"]
    success, crash = summary["success_rate"]["value"], summary["crash_rate"]["value"]
    print(
        f"table1: success {success:.3f}, crash {crash:.3f} (n={summary['success_rate']['n']}); "
        f"training {train['train_wall_s'] / 60:.1f} wall min, {train['train_cpu_s'] / 60:.1f} CPU min"
    )
    assert summary["success_rate"]["n"] == 3000
    assert success >= RULE_FSM_TABLE1["success_rate"], summary["success_rate"]
    assert crash <= RULE_FSM_TABLE1["crash_rate"], summary["crash_rate"]

    root = tmp_path / "lb"
    overtakezoo(
        "submit", "table1.json", "--name", "my-sb3-dqn", "--policy", "model.zip", "--root", str(root), cwd=tmp_path
    )
    out = overtakezoo("leaderboard", "--root", str(root), "--verify", cwd=tmp_path)
    assert "verified submissions/table1/my-sb3-dqn.json: 3000 of 3000 scenarios reproduce exactly" in out, out
