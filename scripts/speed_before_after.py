"""Core throughput of this checkout against an earlier commit, measured in one run.

    python scripts/speed_before_after.py 7d5407d [--sizes 1 64 4096] [--rounds 5]

The earlier commit is checked out into a temporary git worktree and imported through PYTHONPATH;
the two trees are measured alternately, round after round (each measurement a fresh process), so
both see the same machine load. Prints env-steps/s (median of the rounds) and after/before ratios.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PROBE = ("import json, sys; from overtakezoo.benchmark.perf import core_rates; "
         "print(json.dumps(core_rates(int(sys.argv[1]), float(sys.argv[2]), 1)[0]))")


def rate(pythonpath: str | None, n: int, seconds: float) -> float:
    env = dict(os.environ)
    if pythonpath:
        env["PYTHONPATH"] = pythonpath
    out = subprocess.run([sys.executable, "-c", PROBE, str(n), str(seconds)], env=env, cwd=tempfile.gettempdir(),
                         capture_output=True, text=True, check=True)
    return float(json.loads(out.stdout.strip().splitlines()[-1]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before", help="the earlier commit")
    ap.add_argument("--sizes", type=int, nargs="+", default=[1, 64, 4096])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--seconds", type=float, default=1.0)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tree = Path(tmp) / "tree"
        subprocess.run(["git", "-C", str(REPO), "worktree", "add", "-q", "--detach", str(tree), args.before], check=True)
        try:
            (Path(tmp) / "pkg").mkdir()
            (Path(tmp) / "pkg" / "overtakezoo").symlink_to(tree)  # the flat layout, importable as overtakezoo
            trees = {"before": str(Path(tmp) / "pkg"), "after": None}
            rates = {(name, n): [] for name in trees for n in args.sizes}
            for _ in range(args.rounds):
                for n in args.sizes:
                    for name, path in trees.items():
                        rates[name, n].append(rate(path, n, args.seconds))
        finally:
            subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force", str(tree)], check=False)
    print(f"core env-steps/s, median of {args.rounds} alternating rounds ({args.before} vs this checkout)")
    print("| N | before | after | after / before |\n|---|---|---|---|")
    for n in args.sizes:
        before, after = statistics.median(rates["before", n]), statistics.median(rates["after", n])
        print(f"| {n} | {before:,.0f} | {after:,.0f} | {after / before:.3f} |")


if __name__ == "__main__":
    main()
