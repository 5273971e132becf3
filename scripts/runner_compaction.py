"""What dropping finished rows saves the runner: a whole suite run with the batch kept whole and
with finished rows dropped (benchmark/run/runner.py, ``Compaction``), interleaved, in CPU seconds.

    python scripts/runner_compaction.py [--suite table1] [--deciders rule-fsm ppo dqn fuzzy] [--rounds 3]

Prints a markdown table: the median CPU time of each, their ratio, and whether every per-scenario
array was the same bits (it must be).
"""

from __future__ import annotations

import argparse
import time
from functools import partial

import numpy as np

from overtakezoo.benchmark.run import runner
from overtakezoo.benchmark.run.perf import interleave, timed
from overtakezoo.benchmark.run.policy import load_zoo
from overtakezoo.envs.suites import load_suite

NEVER = 10**9  # a floor no batch reaches: the runner steps the whole batch


def run_cpu(suite, name: str, floor: int, per: dict[int, dict[str, np.ndarray]]) -> float:
    """CPU seconds of one run of ``suite`` with a fresh ``name`` at compaction floor ``floor``
    (loading the decider not counted); its per-scenario arrays go to ``per[floor]``."""
    runner.MIN_COMPACT_ROWS = floor
    decider = load_zoo(name, suite.config)
    run = partial(runner.run_suite, suite, decider, progress=False)
    return timed(lambda: per.__setitem__(floor, run().per), time.process_time)()


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
        per: dict[int, dict[str, np.ndarray]] = {}
        try:
            times = interleave(
                {floor: partial(run_cpu, suite, name, floor, per) for floor in (NEVER, default)},
                args.rounds,
            )
        finally:
            runner.MIN_COMPACT_ROWS = default
        same = all(
            np.array_equal(per[NEVER][k], per[default][k], equal_nan=per[NEVER][k].dtype.kind == "f")
            for k in per[NEVER]
        )
        whole, dropped = times[NEVER]["median"], times[default]["median"]
        print(f"| {name} | {whole:.2f} | {dropped:.2f} | {whole / dropped:.2f}x | {'yes' if same else 'NO'} |")


if __name__ == "__main__":
    main()
