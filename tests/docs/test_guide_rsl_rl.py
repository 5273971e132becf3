"""The guide docs/guides/rsl-rl.md works as written (its code block names this test):
examples/rsl_rl_ppo.py trains rsl-rl's own OnPolicyRunner on table1-train (the zoo's 1 s hold), exports
with rsl-rl's own ONNX exporter and writes the policy card; the exported file then evaluates on table1
to the guide's target, submits to a leaderboard and verifies there."""

from __future__ import annotations

from pathlib import Path

import pytest

from guide_cli import run_example
from overtakezoo.benchmark.cli import main
from overtakezoo.benchmark.results.results import Results

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "rsl_rl_ppo.py"


@pytest.mark.slow
def test_rsl_rl_guide_trains_exports_evaluates_submits_and_verifies(tmp_path, capsys):
    pytest.importorskip("rsl_rl")
    pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    minutes = run_example(
        EXAMPLE, "--iterations", "60", "--seed", "0", "--out", "runs/rsl-ppo", cwd=tmp_path, timeout=1800
    )
    policy = tmp_path / "runs" / "rsl-ppo" / "policy.onnx"
    assert policy.is_file()
    print(f"training + export: {minutes:.1f} min")
    assert minutes < 15

    out = tmp_path / "runs" / "rsl-ppo" / "table1.json"
    assert main(["eval", "--suite", "table1", "--policy", str(policy), "--out", str(out), "--no-progress"]) == 0, (
        capsys.readouterr().err
    )
    capsys.readouterr()
    summary = Results.load(out).summary
    success, crash = summary["success_rate"]["value"], summary["crash_rate"]["value"]
    with capsys.disabled():
        print(f"\nrsl-rl guide: training {minutes:.1f} min; table1 success {success:.1%}, crash {crash:.1%}")
    assert success >= 0.71 and crash <= 0.29

    root = tmp_path / "my-lb"
    assert main(["submit", str(out), "--name", "my-rsl-ppo", "--policy", str(policy), "--root", str(root)]) == 0, (
        capsys.readouterr().err
    )
    capsys.readouterr()
    assert main(["leaderboard", "--root", str(root), "--verify"]) == 0, capsys.readouterr().err
    assert "verified submissions/table1/my-rsl-ppo.json: 3000 of 3000 scenarios reproduce" in capsys.readouterr().out
