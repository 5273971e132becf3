"""`--policy mymodule:factory` resolves `mymodule` from the current directory, as `python -m` does
(the `overtakezoo` console script has no current directory on sys.path of its own)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from conftest import suite_file

FACTORY = """
import numpy as np

class Lefty:
    name = "lefty"
    def act(self, obs):
        return np.ones(len(obs), np.int64)

def make(config):
    return Lefty()
"""


def test_module_factory_resolves_from_the_current_directory(tmp_path):
    (tmp_path / "mypolicy.py").write_text(FACTORY)
    suite_file(tmp_path / "tiny.toml", 4)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    # -P: no script directory or cwd put on sys.path, as for the installed `overtakezoo` script
    cmd = [
        sys.executable,
        "-P",
        "-c",
        "import sys; from overtakezoo.benchmark.cli import main; sys.exit(main())",
        "eval",
        "--suite",
        "tiny.toml",
        "--policy",
        "mypolicy:make",
        "--out",
        "r.json",
        "--no-progress",
    ]
    done = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    doc = json.loads((tmp_path / "r.json").read_text())
    assert doc["decider"]["name"] == "lefty" and doc["decider"]["policy"] == {"kind": "module", "spec": "mypolicy:make"}
    missing = subprocess.run(
        cmd[:5] + ["--suite", "tiny.toml", "--policy", "nothere:make"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert (
        missing.returncode == 2 and missing.stderr.startswith("error: ") and "cannot import nothere" in missing.stderr
    )
