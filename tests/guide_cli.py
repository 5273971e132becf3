"""What the guides' slow tests share: the `overtakezoo` command run as a user runs it, and the bar
every guide's policy must clear (rule-fsm's table1 figures, leaderboards/table1.md)."""

import os
import subprocess
import sys
import time
from pathlib import Path

RULE_FSM_TABLE1 = {"success_rate": 0.71, "crash_rate": 0.29}


def overtakezoo(*args: str, cwd: Path) -> str:
    """Run the CLI in ``cwd`` (the installed script when there is one); its stdout, or a failed assert."""
    cli = Path(sys.executable).with_name("overtakezoo")
    command = (
        [str(cli)]
        if cli.is_file()
        else [sys.executable, "-c", "import sys; from overtakezoo.benchmark.cli import main; sys.exit(main())"]
    )
    done = subprocess.run(command + list(args), cwd=cwd, capture_output=True, text=True)
    assert done.returncode == 0, f"overtakezoo {' '.join(args)}:\n{done.stdout}\n{done.stderr}"
    return done.stdout


def run_example(example: Path, *args: str, cwd: Path, timeout: float) -> float:
    """Run an example script as its guide writes it (from ``cwd``, a directory of the user's own), torch
    at one thread; its wall minutes, or a failed assert with the end of its output."""
    t0 = time.perf_counter()
    done = subprocess.run(
        [sys.executable, str(example), *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        env=dict(os.environ, OMP_NUM_THREADS="1"),
        timeout=timeout,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return (time.perf_counter() - t0) / 60
