"""What dropping finished rows saves the runner: a whole suite run with the batch kept whole and
with finished rows dropped (benchmark/run/runner.py, ``Compaction``), interleaved, in CPU seconds.

    python scripts/runner_compaction.py [--suite table1] [--deciders rule-fsm ppo dqn fuzzy] [--rounds 3]

Prints a markdown table: the median CPU time of each, their ratio, and whether every per-scenario
array was the same bits (it must be).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from overtakezoo.benchmark.run import runner
from overtakezoo.benchmark.run.policy import load_zoo
from overtakezoo.envs.suites import load_suite

NEVER = 10**9  # a floor no batch reaches: the runner steps the whole batch


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--suite", default="table1")
    ap.add_argument("--deciders", nargs="+", default=["rule-fsm", "ppo", "dqn", "fuzzy"])
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    suite, default = load_suite(args.suite), runner.MIN_COMPACT_ROWS
    print(
        "| decider | whole batch (CPU s) | finished rows dropped (CPU s) | ratio | same bits |\n|---|---|---|---|---|"
    )
    for name in args.deciders:
        times: dict[int, list[float]] = {NEVER: [], default: []}
        per: dict[int, dict[str, np.ndarray]] = {}
        for _ in range(args.rounds):
            for floor in (NEVER, default):
                runner.MIN_COMPACT_ROWS = floor
                decider = load_zoo(name, suite.config)
                t0 = time.process_time()
                per[floor] = runner.run_suite(suite, decider, progress=False).per
                times[floor].append(time.process_time() - t0)
        runner.MIN_COMPACT_ROWS = default
        same = all(
            np.array_equal(per[NEVER][k], per[default][k], equal_nan=per[NEVER][k].dtype.kind == "f")
            for k in per[NEVER]
        )
        whole, dropped = statistics.median(times[NEVER]), statistics.median(times[default])
        print(f"| {name} | {whole:.2f} | {dropped:.2f} | {whole / dropped:.2f}x | {'yes' if same else 'NO'} |")


if __name__ == "__main__":
    main()
