"""The learned members act through numpy: `eval` of dqn / double-dqn / ppo imports no torch (nor
rsl-rl, nor the other heavy optional libraries), and the trainers' .npz + card load by file, card or
directory."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from conftest import shipped_weights_current, suite_file

HEAVY = ("torch", "rsl_rl", "tensordict", "matplotlib", "mcap", "minari", "ray")

SCRIPT = """
import json, sys
import numpy as np
from overtakezoo import zoo
from overtakezoo.benchmark.cli import main
from overtakezoo.envs import EnvConfig, observation_size

directory, suite, out, name, shipped = sys.argv[1:6]
dec = zoo.load(name) if shipped == "1" else zoo.load(name, directory=directory)
modes = dec.act(np.zeros((3, observation_size(EnvConfig()))))
spec = ["--decider", name] if shipped == "1" else ["--policy", directory + "/" + name + ".npz"]
rc = main(["eval", "--suite", suite, *spec, "--out", out, "--no-progress"])
print(json.dumps({"rc": rc, "modes": modes.tolist(), "loaded": [m for m in %r if m in sys.modules]}))
""" % (HEAVY,)  # noqa: UP031 (the script's own braces rule out str.format and f-strings)


@pytest.fixture
def suite(tmp_path):
    return suite_file(tmp_path / "tiny.toml", 4, time_limit=10.0)


@pytest.mark.parametrize("name", ["dqn", "ppo"])
def test_loading_acting_and_eval_of_a_learned_member_import_no_torch(tmp_path, suite, learned_dir, name):
    # The shipped weights when they fit the observation; else random ones in the same format.
    shipped = "1" if shipped_weights_current(name) else "0"
    out = tmp_path / "r.json"
    proc = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(learned_dir), str(suite), str(out), name, shipped],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    assert report["rc"] == 0 and len(report["modes"]) == 3
    assert report["loaded"] == [], f"imported {report['loaded']} to evaluate {name}"
    assert json.loads(out.read_text())["decider"]["weights_sha256"]
