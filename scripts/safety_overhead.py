"""The safety monitor's cost in `eval`: run_suite with and without it, interleaved in one process,
CPU seconds (time.process_time), median of ROUNDS. Usage: python scripts/safety_overhead.py [SUITE] [DECIDER ...]"""

import sys
import time
from functools import partial

from overtakezoo import zoo
from overtakezoo.benchmark.run.perf import interleave, timed
from overtakezoo.benchmark.run.runner import run_suite
from overtakezoo.envs.suites import load_suite

ROUNDS = 9
suite = load_suite(sys.argv[1] if len(sys.argv) > 1 else "table1")
for name in sys.argv[2:] or ["rule-fsm", "dqn"]:
    decider = zoo.load(name, suite.config)
    run_suite(suite, decider, progress=False)  # warm-up (imports, caches)
    cpu = interleave(
        {
            s: timed(partial(run_suite, suite, decider, progress=False, safety=s), time.process_time)
            for s in (False, True)
        },
        ROUNDS,
    )
    off, on = cpu[False]["median"], cpu[True]["median"]
    print(f"{suite.name} {name}: without {off:.3f} s, with {on:.3f} s CPU (median of {ROUNDS}): x{on / off:.3f}")
