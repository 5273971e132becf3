"""What dropping finished rows saves the runner: a whole suite run with the batch kept whole and
with finished rows dropped (benchmark/run/runner.py, ``Compaction``), interleaved, in CPU seconds.

    python scripts/runner_compaction.py [--suite table1] [--deciders rule-fsm ppo dqn fuzzy] [--rounds 3]
                                        [--json docs/runner-compaction.json]

Prints a markdown table: the median CPU time of each, the median of their per-round ratios, and
whether every per-scenario array was the same bits (it must be). ``--json PATH`` also writes every figure under an id
(``<decider>-whole``, ``<decider>-dropped``, ``<decider>-ratio``: median, min, max, runs) with the
date, the machine and the load average to PATH, atomically (docs/performance.md quotes it).
"""

from __future__ import annotations

import argparse
import time
from functools import partial

import numpy as np

from overtakezoo.benchmark.run import runner
from overtakezoo.benchmark.run.perf import interleave, load_average, machine, spread, timed
from overtakezoo.benchmark.run.policy import load_zoo
from overtakezoo.envs.io import atomic_write_json
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
    ap.add_argument(
        "--json", metavar="PATH", help="also write every figure by id to PATH (docs/runner-compaction.json)"
    )
    args = ap.parse_args()
    doc = {
        "generated_by": "python scripts/runner_compaction.py" + (f" --json {args.json}" if args.json else ""),
        "date": time.strftime("%Y-%m-%d %H:%M"),
        "machine": machine(),
        "suite": args.suite,
        "rounds": args.rounds,
        "load_average_at_start": load_average(),
    }
    figures = []
    what = f"a whole {args.suite} run in the runner, {args.rounds} interleaved rounds, CPU time (loading not counted)"
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
        ratio = spread([x / y for x, y in zip(times[NEVER]["runs"], times[default]["runs"], strict=True)])
        print(f"| {name} | {whole:.2f} | {dropped:.2f} | {ratio['median']:.2f}x | {'yes' if same else 'NO'} |")
        for fid, s, unit, how in (
            ("whole", times[NEVER], "CPU s", "the whole batch stepped to the end"),
            ("dropped", times[default], "CPU s", "finished rows dropped (the runner's default)"),
            ("ratio", ratio, "x", "whole batch / finished rows dropped, per round"),
        ):
            rounded = {k: round(s[k], 3) for k in ("median", "min", "max")}
            runs = [round(x, 3) for x in s["runs"]]
            figures.append(
                {"id": f"{name}-{fid}", **rounded, "runs": runs, "unit": unit, "what": f"{name}, {what}: {how}"}
            )
        figures.append(
            {"id": f"{name}-same-bits", "value": same, "what": f"{name}: every per-scenario array the same bits"}
        )
    if args.json:
        doc["figures"] = figures
        doc["load_average_at_end"] = load_average()
        atomic_write_json(args.json, doc)


if __name__ == "__main__":
    main()
