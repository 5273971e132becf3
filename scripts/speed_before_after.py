"""Core throughput of this checkout against an earlier commit, measured in one run.

    python scripts/speed_before_after.py 7d5407d [--sizes 1 64 4096] [--rounds 5] [--suite oncoming-8]

The earlier commit is checked out into a temporary git worktree and imported through PYTHONPATH;
the two trees are measured alternately, round after round (each measurement a fresh process), so
both see the same machine load; each is timed in CPU seconds. Prints env-steps per CPU second (median
of the rounds) and after/before ratios.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from functools import partial
from pathlib import Path

from overtakezoo.benchmark.run.perf import interleave

REPO = Path(__file__).resolve().parents[1]
# The core as `overtakezoo perf` steps it (auto-reset, always OVERTAKE), timed in CPU seconds of this
# process: helpers and other jobs on a shared machine then slow both trees alike far less than in wall time.
PROBE = """
import sys, time
import numpy as np
from overtakezoo.envs import EnvConfig, OvertakeCore, ScenarioDistribution
n, seconds, suite = int(sys.argv[1]), float(sys.argv[2]), sys.argv[3]
if suite == "-":  # the env's defaults, as `overtakezoo perf` measures
    dist, cfg = ScenarioDistribution(), EnvConfig()
else:
    from overtakezoo.envs.suites import load_suite
    dist, cfg = load_suite(suite).distribution, load_suite(suite).config
core = OvertakeCore(cfg, auto_reset=True, source=lambda k, rng: dist.sample(k, rng), seed=0)
core.reset(dist.sample(n, 0))
modes = np.full(n, 1)
for _ in range(20):
    core.step(modes)
steps, start = 0, time.process_time()
while time.process_time() - start < seconds:
    for _ in range(5):
        core.step(modes)
    steps += 5
print(steps * n / (time.process_time() - start))
"""


def rate(pythonpath: str | None, n: int, seconds: float, suite: str) -> float:
    env = dict(os.environ)
    if pythonpath:
        env["PYTHONPATH"] = pythonpath
    env["OMP_NUM_THREADS"] = "1"  # one core per probe: the figure is the model's cost, not the machine's spare cores
    out = subprocess.run(
        [sys.executable, "-c", PROBE, str(n), str(seconds), suite],
        env=env,
        cwd=tempfile.gettempdir(),
        capture_output=True,
        text=True,
        check=True,
    )
    return float(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before", help="the earlier commit")
    ap.add_argument("--sizes", type=int, nargs="+", default=[1, 64, 4096])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--seconds", type=float, default=1.0)
    ap.add_argument("--suite", default="-", help="step this suite's scenarios and settings (default: the env's)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tree = Path(tmp) / "tree"
        subprocess.run(
            ["git", "-C", str(REPO), "worktree", "add", "-q", "--detach", str(tree), args.before], check=True
        )
        try:
            (Path(tmp) / "pkg").mkdir()
            (Path(tmp) / "pkg" / "overtakezoo").symlink_to(tree)  # the flat layout, importable as overtakezoo
            trees = {"before": str(Path(tmp) / "pkg"), "after": None}
            # round after round: every size, each tree in turn
            probes = {
                (name, n): partial(rate, path, n, args.seconds, args.suite)
                for n in args.sizes
                for name, path in trees.items()
            }
            rates = interleave(probes, args.rounds)
        finally:
            subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force", str(tree)], check=False)
    print(
        f"core env-steps per CPU second, median of {args.rounds} alternating rounds ({args.before} vs this checkout, "
        f"{'the env defaults' if args.suite == '-' else 'suite ' + args.suite})"
    )
    print("| N | before | after | after / before |\n|---|---|---|---|")
    for n in args.sizes:
        before, after = rates["before", n]["median"], rates["after", n]["median"]
        print(f"| {n} | {before:,.0f} | {after:,.0f} | {after / before:.3f} |")


if __name__ == "__main__":
    main()
