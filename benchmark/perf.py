"""Throughput of the batched core and of one PettingZoo env (a benchmark script, not a test).

    python -m overtakezoo.benchmark.perf [--sizes 1 256 4096] [--seconds 3] [--json out.json]

Env-steps/s count scenario-steps: N rows stepped once = N env-steps. The planner runs every step.
Rows are auto-reset so the batch stays full of live scenarios.
"""

from __future__ import annotations

import argparse
import json
import platform
import time

import numpy as np

from overtakezoo.envs import OVERTAKE, EnvConfig, OvertakeCore, ScenarioDistribution


def core_steps_per_second(n: int, seconds: float = 3.0, seed: int = 0) -> float:
    dist = ScenarioDistribution()
    core = OvertakeCore(EnvConfig(), auto_reset=True, source=lambda k, rng: dist.sample(k, rng), seed=seed)
    core.reset(dist.sample(n, seed))
    modes = np.full(n, OVERTAKE)
    for _ in range(3):  # warm-up
        core.step(modes)
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        for _ in range(10):
            core.step(modes)
        steps += 10
    return n * steps / (time.perf_counter() - start)


def pettingzoo_steps_per_second(seconds: float = 3.0, seed: int = 0) -> float:
    from overtakezoo.envs import parallel_env

    env = parallel_env()
    env.reset(seed=seed)
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        if not env.agents:
            env.reset(seed=seed + steps)
        env.step({agent: 1 for agent in env.agents})
        steps += 1
    return steps / (time.perf_counter() - start)


def machine() -> str:
    import os

    return f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 256, 4096])
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--json", help="also write the figures to this JSON file")
    args = parser.parse_args(argv)
    report = {"machine": machine(), "core_env_steps_per_s": {}}
    for n in args.sizes:
        rate = core_steps_per_second(n, args.seconds)
        report["core_env_steps_per_s"][str(n)] = round(rate)
        print(f"core N={n:>6}: {rate:>12,.0f} env-steps/s")
    try:
        rate = pettingzoo_steps_per_second(args.seconds)
        report["pettingzoo_steps_per_s"] = round(rate)
        print(f"PettingZoo env: {rate:>12,.0f} steps/s")
    except ImportError:
        print("PettingZoo face not available")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(report, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
