"""OvertakeZoo beside d3rlpy (docs/guides/offline-rl.md, whose code block names this test): one fresh venv
(no system site packages) with ``overtakezoo[data,onnx,d3rlpy]`` and torch 2.13.0 resolves gymnasium to
1.0.x (d3rlpy 2.8 pins 1.0.0), imports and runs the package (the env/face tests, a rule-fsm table1
eval), and examples/d3rlpy_cql.py as written trains DiscreteCQL from ``overtakezoo/table1/rule-fsm-v0``
(a few hundred gradient steps here) and saves an ONNX policy that ``eval --policy`` evaluates into a
valid results file.

Needs network (PyPI) to build the venv; pip's cache, the venv and the dataset (rebuilt from its
recipe when no mirror answers) stay in the test's tmp dir.

    python -m pytest -m slow tests/docs/test_d3rlpy.py -q
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from overtakezoo.benchmark.results.results import Results

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "examples" / "d3rlpy_cql.py"
STEPS = 300
ENV_TESTS = [
    "tests/envs/test_faces.py",
    "tests/envs/test_env_citizen.py",
    "tests/envs/test_suite_envs.py",
    "tests/envs/test_gym_compat.py",
]


def run(command: list[str], cwd: Path, env: dict[str, str], timeout: float = 1800) -> str:
    done = subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, f"{' '.join(command)}:\n{done.stdout[-4000:]}\n{done.stderr[-4000:]}"
    return done.stdout


@pytest.fixture(scope="module")
def d3venv(tmp_path_factory):
    """(python, overtakezoo CLI, env) of a fresh venv with overtakezoo[data,onnx,d3rlpy] and torch 2.13.0."""
    root = tmp_path_factory.mktemp("d3rlpy")
    venv = root / "venv"
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env.update(
        PIP_CACHE_DIR=str(root / "pip-cache"),
        PIP_DISABLE_PIP_VERSION_CHECK="1",
        OMP_NUM_THREADS="1",
        MINARI_DATASETS_PATH=str(root / "datasets"),
        OVERTAKEZOO_HOME=str(root / "home"),
    )
    run([sys.executable, "-m", "venv", str(venv)], root, env)  # no system site packages
    py = venv / "bin" / "python"
    # torch pinned: unpinned, pip pulls a multi-GB CUDA build. pytest & co. for the env/face tests.
    run(
        [
            str(py),
            "-m",
            "pip",
            "install",
            "-q",
            f"{REPO}[data,onnx,d3rlpy]",
            "torch==2.13.0",
            "pytest>=8",
            "pytest-benchmark>=4",
            "hypothesis>=6",
        ],
        root,
        env,
    )
    return py, venv / "bin" / "overtakezoo", env, root


def test_gymnasium_resolves_to_1_0_and_the_package_runs(d3venv):
    py, cli, env, root = d3venv
    out = run(
        [
            str(py),
            "-c",
            "import gymnasium, d3rlpy, overtakezoo.envs, gymnasium.vector as v; "
            "print(gymnasium.__version__, d3rlpy.__version__, hasattr(v, 'AutoresetMode'))",
        ],
        root,
        env,
    )
    gym_version, d3_version, has_mode = out.split()
    assert gym_version.startswith("1.0."), out
    assert d3_version.startswith("2.8."), out
    assert has_mode == "False", out  # so the env runs on envs/faces/_compat.py's stand-in
    run(
        [str(cli), "eval", "--suite", "table1", "--decider", "rule-fsm", "--out", "rule-fsm.json", "--no-progress"],
        root,
        env,
    )
    summary = Results.load(root / "rule-fsm.json").to_dict()["summary"]
    assert summary["success_rate"]["n"] == 3000


def test_env_and_face_tests_pass_on_gymnasium_1_0(d3venv):
    py, _, env, _ = d3venv
    # -p no:cacheprovider: nothing written into the repository
    out = run([str(py), "-m", "pytest", "-p", "no:cacheprovider", *ENV_TESTS], REPO, env)  # -q from addopts
    assert " passed" in out and " failed" not in out and " error" not in out, out[-2000:]


def test_d3rlpy_cql_example_trains_and_evaluates(d3venv):
    py, cli, env, root = d3venv
    work = root / "cql"
    work.mkdir()
    run([str(py), str(EXAMPLE), "--steps", str(STEPS), "--seed", "0", "--out", "."], work, env)
    train = json.loads((work / "train.json").read_text())
    assert train["steps"] == STEPS and train["threads"] == 1 and train["transitions"] > 100_000, train
    card = json.loads(
        run(
            [
                str(py),
                "-c",
                "import json, onnx; m = onnx.load('policy.onnx'); "
                "print({p.key: p.value for p in m.metadata_props}['overtakezoo.card'])",
            ],
            work,
            env,
        )
    )
    assert card["action_repeat"] == 1 and card["suite"] == "table1-train", card

    run(
        [str(cli), "eval", "--suite", "table1", "--policy", "policy.onnx", "--out", "table1.json", "--no-progress"],
        work,
        env,
    )
    results = Results.load(work / "table1.json")  # validates against the results schema
    doc = results.to_dict()
    assert doc["decider"]["policy"]["kind"] == "onnx"
    summary = doc["summary"]
    assert summary["success_rate"]["n"] == 3000
    rates = [summary[k]["value"] for k in ("success_rate", "crash_rate", "timeout_rate")]
    assert all(0.0 <= r <= 1.0 for r in rates) and sum(rates) <= 1.0 + 1e-9, summary
    print(f"d3rlpy cql, {STEPS} steps: table1 success {rates[0]:.3f}, crash {rates[1]:.3f}, timeout {rates[2]:.3f}")
