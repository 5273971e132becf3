"""Performance report: throughput of the core, one PettingZoo env, whole suites, memory, and
highway-env's ``two-way-v0`` measured side by side on the same machine.

    overtakezoo perf [--sizes 1 256 4096 16384] [--seconds 3] [--out docs/perf]

Env-steps/s count scenario-steps (N rows stepped once = N env-steps, the planner included; rows
are auto-reset so the batch stays full). Simulated seconds per wall second = env-steps/s x dt.
"""

from __future__ import annotations

import os
import platform
import sys
import time
from typing import Any

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
        for _ in range(5):
            core.step(modes)
        steps += 5
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


def suite_wall_time(suite: str, decider: str) -> dict[str, Any]:
    """Wall time of a whole suite run in the runner (scenario generation and decider included;
    process start-up and imports not)."""
    from overtakezoo import zoo
    from overtakezoo.benchmark.runner import run_suite
    from overtakezoo.benchmark.suites import load_suite

    s = load_suite(suite)
    d = zoo.load(decider, config=s.config)
    start = time.perf_counter()
    result = run_suite(s, d, progress=False)
    wall = time.perf_counter() - start
    return {"suite": suite, "decider": decider, "scenarios": s.count, "wall_time_s": round(wall, 2),
            "success_rate": round(float(result.summary["success_rate"]["value"]), 4),
            "simulated_s": round(float(np.sum(result.per_scenario_array("episode_time"))), 1)}


def peak_memory_per_1000_scenarios(suite: str = "table1", decider: str = "rule-fsm") -> float:
    """Peak memory (MiB) a whole-suite run allocates (numpy arrays included: numpy reports its
    allocations to tracemalloc), per 1000 scenarios."""
    import tracemalloc

    from overtakezoo import zoo
    from overtakezoo.benchmark.runner import run_suite
    from overtakezoo.benchmark.suites import load_suite

    s = load_suite(suite)
    d = zoo.load(decider, config=s.config)
    tracemalloc.start()
    try:
        run_suite(s, d, progress=False)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    return round(peak / 2**20 / (s.count / 1000), 2)


def highway_env_sim_seconds_per_second(seconds: float = 5.0) -> dict[str, Any] | None:
    """highway-env's ``two-way-v0`` (the only packaged overtaking-with-oncoming-traffic env), stepped
    with the IDLE action on one core; None when the ``[compare]`` extra is not installed."""
    try:
        import gymnasium as gym
        import highway_env  # noqa: F401  (registers two-way-v0 on import)
    except ImportError:
        return None
    env = gym.make("two-way-v0")
    env.reset(seed=0)
    per_decision = 1.0 / env.unwrapped.config["policy_frequency"]
    decisions, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        _, _, terminated, truncated, _ = env.step(1)
        decisions += 1
        if terminated or truncated:
            env.reset()
    elapsed = time.perf_counter() - start
    import importlib.metadata as md

    return {"version": md.version("highway-env"), "decisions_per_s": round(decisions / elapsed, 1),
            "sim_seconds_per_wall_second": round(decisions * per_decision / elapsed, 1)}


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, numpy {np.__version__}"


def measure(sizes: list[int], seconds: float, suites: bool = True, progress=print) -> dict[str, Any]:
    dt = EnvConfig().dt
    report: dict[str, Any] = {"machine": machine(), "date": time.strftime("%Y-%m-%d"), "core": {}}
    for n in sizes:
        rate = core_steps_per_second(n, seconds)
        report["core"][str(n)] = {"env_steps_per_s": round(rate), "sim_seconds_per_wall_second": round(rate * dt)}
        progress(f"core N={n:>6}: {rate:>12,.0f} env-steps/s")
    try:
        report["pettingzoo_steps_per_s"] = round(pettingzoo_steps_per_second(seconds))
        progress(f"PettingZoo env: {report['pettingzoo_steps_per_s']:,} steps/s")
    except ImportError:
        report["pettingzoo_steps_per_s"] = None
    if suites:
        report["suites"] = []
        for decider in ("rule-fsm", "dqn"):
            try:
                row = suite_wall_time("table1", decider)
            except Exception as exc:  # a member missing from this install is reported, not fatal
                row = {"suite": "table1", "decider": decider, "error": str(exc).splitlines()[0]}
            report["suites"].append(row)
            progress(f"table1 / {decider}: {row.get('wall_time_s', row.get('error'))} s")
        report["peak_memory_mib_per_1000_scenarios"] = peak_memory_per_1000_scenarios()
        progress(f"peak memory: {report['peak_memory_mib_per_1000_scenarios']} MiB per 1000 scenarios")
    hw = highway_env_sim_seconds_per_second(seconds)
    report["highway_env"] = hw
    if hw:
        best = max(v["sim_seconds_per_wall_second"] for v in report["core"].values())
        single = report["core"].get("1", {}).get("sim_seconds_per_wall_second")
        report["ratio_vs_highway_env"] = {"batched": round(best / hw["sim_seconds_per_wall_second"], 1),
                                          "single_env": round(single / hw["sim_seconds_per_wall_second"], 1) if single else None}
        progress(f"highway-env two-way-v0: {hw['sim_seconds_per_wall_second']} sim s / wall s; "
                 f"ratio {report['ratio_vs_highway_env']}")
    return report


def to_markdown(report: dict[str, Any]) -> str:
    lines = ["# Performance report", "", f"Machine: {report['machine']} ({report['date']}).", "",
             "| measurement | value |", "|---|---|"]
    for n, row in report["core"].items():
        lines.append(f"| core, N = {n} | {row['env_steps_per_s']:,} env-steps/s "
                     f"({row['sim_seconds_per_wall_second']:,} simulated s per wall s) |")
    if report.get("pettingzoo_steps_per_s"):
        lines.append(f"| one PettingZoo env | {report['pettingzoo_steps_per_s']:,} steps/s |")
    for row in report.get("suites", []):
        value = f"{row['wall_time_s']} s" if "wall_time_s" in row else f"not measured: {row['error']}"
        lines.append(f"| {row['suite']} ({row.get('scenarios', '?')} scenarios) with {row['decider']}, whole run in "
                     f"the runner (scenarios, decider, simulation) | {value} |")
    if report.get("peak_memory_mib_per_1000_scenarios") is not None:
        lines.append(f"| peak memory of a table1 run (rule-fsm), per 1000 scenarios | "
                     f"{report['peak_memory_mib_per_1000_scenarios']} MiB |")
    hw = report.get("highway_env")
    if hw:
        lines.append(f"| highway-env {hw['version']} two-way-v0 | {hw['decisions_per_s']} decisions/s = "
                     f"{hw['sim_seconds_per_wall_second']} simulated s per wall s |")
        r = report["ratio_vs_highway_env"]
        lines.append(f"| ratio to highway-env (simulated s per wall s) | {r['batched']}x batched, {r['single_env']}x one env |")
    return "\n".join(lines) + "\n"


def write_report(report: dict[str, Any], out_prefix: str) -> None:
    from .io import atomic_write_json, atomic_write_text

    atomic_write_json(out_prefix + ".json", report)
    atomic_write_text(out_prefix + ".md", to_markdown(report))


if __name__ == "__main__":
    from .cli import main

    raise SystemExit(main(["perf", *sys.argv[1:]]))
