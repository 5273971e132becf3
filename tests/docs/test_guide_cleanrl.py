"""The guide docs/guides/cleanrl.md as written (its code block names this test): examples/cleanrl_ppo.py trains PPO on
overtakezoo/table1-train-v2 (one file, torch at one thread), exports the actor to ONNX with its policy
card; the exported file then evaluates on table1 to at least rule-fsm's success (0.71) at no more than
its crash rate (0.29), submits into a fresh leaderboard folder and verifies there. Seed 0; on CPU at one
torch thread the run is deterministic on one machine (the same policy.onnx bytes twice).

    python -m pytest -m slow tests/docs/test_guide_cleanrl.py -q
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from guide_cli import RULE_FSM_TABLE1, overtakezoo, run_example

pytest.importorskip("torch")
pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "examples" / "cleanrl_ppo.py"


def test_cleanrl_guide_trains_past_rule_fsm_then_submits_and_verifies(tmp_path):
    total_min = run_example(EXAMPLE, "--seed", "0", "--out", "runs/cleanrl-ppo", cwd=tmp_path, timeout=1800)
    run = tmp_path / "runs" / "cleanrl-ppo"
    policy = run / "policy.onnx"
    assert policy.is_file()
    train = json.loads((run / "train.json").read_text())
    train_min = train["train_wall_s"] / 60
    assert train["threads"] == 1 and train_min <= 15, train

    import onnx

    props = {p.key: p.value for p in onnx.load(str(policy)).metadata_props}
    card = json.loads(props["overtakezoo.card"])
    assert card["action_repeat"] == 10 and card["suite"] == "table1-train"

    printed = overtakezoo(
        "eval",
        "--suite",
        "table1",
        "--policy",
        "runs/cleanrl-ppo/policy.onnx",
        "--out",
        "runs/cleanrl-ppo/table1.json",
        "--no-progress",
        cwd=tmp_path,
    )
    summary = json.loads((run / "table1.json").read_text())["summary"]
    success, crash = summary["success_rate"], summary["crash_rate"]
    print(
        f"\ncleanrl guide: {train['decisions']} decisions trained in {train_min:.2f} min wall "
        f"(script {total_min:.1f} min with export); table1 success {success['value']:.3f}, "
        f"crash {crash['value']:.3f} (n={success['n']})"
    )
    print("\n".join(line for line in printed.splitlines() if line.startswith(("successful overtaking", "crash rate"))))
    assert success["n"] == 3000
    assert success["value"] >= RULE_FSM_TABLE1["success_rate"], success
    assert crash["value"] <= RULE_FSM_TABLE1["crash_rate"], crash

    root = tmp_path / "my-lb"
    overtakezoo(
        "submit",
        "runs/cleanrl-ppo/table1.json",
        "--name",
        "my-cleanrl-ppo",
        "--policy",
        "runs/cleanrl-ppo/policy.onnx",
        "--root",
        str(root),
        cwd=tmp_path,
    )
    out = overtakezoo("leaderboard", "--root", str(root), "--verify", cwd=tmp_path)
    assert "verified submissions/table1/my-cleanrl-ppo.json: 3000 of 3000 scenarios reproduce exactly" in out, out
