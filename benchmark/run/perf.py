"""Performance report: every speed figure the README quotes, measured side by side on one machine.

    overtakezoo perf [--sizes 1 8 256 4096 16384] [--batch 8] [--seconds 1] [--repeats 3] [--out docs/perf]

Each figure is measured ``repeats`` times (a window of ``seconds`` each, or one whole run) and
reported as the median with the range, under a stable id (``core-4096``, ``eval-table1-dqn``...)
that the README cites. Like is compared with like, with N always named: one Gymnasium env of ours
against one highway-env ``two-way-v0`` env, and our ``gymnasium.make_vec`` batch of N against
highway-env's ``make_vec`` batch of N (sync and async), in simulated seconds per wall second (our
step is ``dt`` = 0.1 s; a highway-env step is one decision, 1 / ``policy_frequency`` s).

Env-steps/s count scenario-steps (N rows stepped once = N env-steps, the planner included; rows
are auto-reset so the batch stays full).

Every figure of the report is measured in this one module, so a report is one run of it and like is
measured next to like.
"""

from __future__ import annotations

import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from overtakezoo.envs import OVERTAKE, EnvConfig, OvertakeCore, ScenarioDistribution

HIGHWAY_ID = "two-way-v0"  # highway-env's only packaged overtaking-with-oncoming-traffic env
OUR_ID = "overtakezoo/Overtake-v0"
HIGHWAY_IDLE = 1  # highway-env's discrete meta-action IDLE: keep lane and speed


def spread(values: list[float]) -> dict[str, Any]:
    """Median and range of repeated measurements."""
    return {"median": statistics.median(values), "min": min(values), "max": max(values), "runs": values}


# ----------------------------------------------------------------------------- the timing helper
# Every figure here and in the timing scripts (scripts/archive_overhead.py, runner_compaction.py,
# safety_overhead.py, speed_before_after.py) is repeated and summarised by these three: a *measure*
# is a callable returning one number (seconds, a rate, a size), and its figure is the spread of its runs.
def repeat(measure: Callable[[], float], repeats: int) -> dict[str, Any]:
    """``measure()`` called ``repeats`` times: the :func:`spread` (median, min, max, runs) of what it returned."""
    return interleave({0: measure}, repeats)[0]


def interleave(measures: dict[Any, Callable[[], float]], rounds: int) -> dict[Any, dict[str, Any]]:
    """``rounds`` rounds, each calling every measure once in order (so drifting machine load hits them
    all alike, as an A/B comparison needs): the :func:`spread` of each, by its key."""
    runs: dict[Any, list[float]] = {key: [] for key in measures}
    for _ in range(rounds):
        for key, measure in measures.items():
            runs[key].append(measure())
    return {key: spread(values) for key, values in runs.items()}


def timed(fn: Callable[[], object], clock: Callable[[], float] = time.perf_counter) -> Callable[[], float]:
    """A measure: the seconds of ``clock`` one call of ``fn`` takes (wall time by default;
    ``time.process_time`` for this process's CPU time)."""

    def measure() -> float:
        start = clock()
        fn()
        return clock() - start

    return measure


def windows(step: Callable[[], int], seconds: float, repeats: int) -> list[float]:
    """Rates (units per wall second) of ``repeats`` windows of ``seconds``; ``step`` returns the
    units one call did. The first call is a warm-up and is not timed."""
    step()

    def window() -> float:
        done, start = 0, time.perf_counter()
        while (elapsed := time.perf_counter() - start) < seconds:
            done += step()
        return done / elapsed

    return repeat(window, repeats)["runs"]


def core_rates(n: int, seconds: float, repeats: int, seed: int = 0) -> list[float]:
    """Env-steps/s of the bare batched core at N (auto-reset keeps the batch full)."""
    dist = ScenarioDistribution()
    core = OvertakeCore(EnvConfig(), auto_reset=True, source=lambda k, rng: dist.sample(k, rng), seed=seed)
    core.reset(dist.sample(n, seed))
    modes = np.full(n, OVERTAKE)

    def step() -> int:
        for _ in range(5):
            core.step(modes)
        return 5 * n

    return windows(step, seconds, repeats)


def pettingzoo_rates(seconds: float, repeats: int, seed: int = 0) -> list[float]:
    """Steps/s of one PettingZoo ``parallel_env()`` (one ego), actions as a policy would send them."""
    from overtakezoo.envs import parallel_env

    env = parallel_env()
    env.reset(seed=seed)
    episodes = [seed]

    def step() -> int:
        if not env.agents:
            episodes[0] += 1
            env.reset(seed=episodes[0])
        env.step({agent: OVERTAKE for agent in env.agents})
        return 1

    return windows(step, seconds, repeats)


def gym_rates(env_id: str, action: int, seconds: float, repeats: int) -> list[float]:
    """Steps/s of one ``gymnasium.make(env_id)`` env."""
    import gymnasium as gym

    env = gym.make(env_id)
    env.reset(seed=0)

    def step() -> int:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
        return 1

    try:
        return windows(step, seconds, repeats)
    finally:
        env.close()


def vec_rates(env_id: str, n: int, mode: str | None, action: int, seconds: float, repeats: int) -> list[float]:
    """Env-steps/s of ``gymnasium.make_vec(env_id, num_envs=n)`` (``mode`` None: the env's own
    vector entry point). Finished envs reset themselves (the vector env's auto-reset)."""
    import gymnasium as gym

    kwargs = {} if mode is None else {"vectorization_mode": mode}
    env = gym.make_vec(env_id, num_envs=n, **kwargs)
    env.reset(seed=0)
    actions = np.full(n, action)

    def step() -> int:
        env.step(actions)
        return n

    try:
        return windows(step, seconds, repeats)
    finally:
        env.close()


def suite_wall_times(suite: str, decider: str, repeats: int) -> dict[str, Any]:
    """Wall time of a whole suite run in the runner (scenario generation and decider included;
    process start-up and imports not)."""
    from overtakezoo import zoo
    from overtakezoo.benchmark.run.runner import run_suite
    from overtakezoo.envs.suites import load_suite

    s = load_suite(suite)
    d = zoo.load(decider, config=s.config)
    return {"scenarios": s.count, **repeat(timed(lambda: run_suite(s, d, progress=False)), repeats)}


def eval_process_times(suite: str, decider: str, runs: int) -> list[float]:
    """Wall time of ``overtakezoo eval`` as a fresh process, start to exit (interpreter start-up,
    imports, the run and the results file included)."""
    return eval_process_runs(suite, decider, runs)[0]


def eval_process_runs(suite: str, decider: str, runs: int) -> tuple[list[float], list[float]]:
    """(wall s, user + sys CPU s) of each of ``runs`` ``overtakezoo eval`` processes: the CPU time
    is the figure that a shared, loaded machine disturbs least."""
    with tempfile.TemporaryDirectory() as tmp:
        done = [
            _cli(["eval", "--suite", suite, "--decider", decider, "--out", "results.json"], tmp) for _ in range(runs)
        ]
    return [w for w, _ in done], [c for _, c in done]


def _cli(args: list[str], cwd: str) -> tuple[float, float]:
    """Run ``overtakezoo ARGS`` as a process; returns (wall s, CPU s of the child)."""
    import resource

    cmd = [sys.executable, "-m", "overtakezoo.benchmark.cli", *args, "--no-progress"]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, cwd=cwd)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(args)} failed: {done.stderr.strip().splitlines()[-1:]}")
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def archive_costs(suite: str = "table1", decider: str = "rule-fsm") -> dict[str, float]:
    """An MCAP archive of 1000 episodes (the suite's first 1000 of 3000, the default every-step
    scene): its size in MB and the CPU time of the run with it over the run without it."""
    with tempfile.TemporaryDirectory() as tmp:
        base = ["eval", "--suite", suite, "--decider", decider, "--shard", "0/3", "--out", "r.json"]
        _, plain = _cli(base, tmp)
        _, archived = _cli([*base, "--archive", "run.mcap"], tmp)
        size = os.path.getsize(os.path.join(tmp, "run.mcap"))
    return {"mb": size / 1e6, "cpu_ratio": archived / plain}


def replay_gif_times(runs: int) -> list[float]:
    """Wall time of ``overtakezoo replay --episode 29 --out ep.gif`` as a process: episode 29 of
    rule-fsm on table1-reactive's first 30 scenarios, 246 frames."""
    with tempfile.TemporaryDirectory() as tmp:
        _cli(
            [
                "eval",
                "--suite",
                "table1-reactive",
                "--decider",
                "rule-fsm",
                "--shard",
                "0/100",
                "--out",
                "r.json",
                "--archive",
                "run.mcap",
            ],
            tmp,
        )
        return repeat(lambda: _cli(["replay", "run.mcap", "--episode", "29", "--out", "ep.gif"], tmp)[0], runs)["runs"]


def peak_memory_per_1000_scenarios(suite: str = "table1", decider: str = "rule-fsm") -> float:
    """Peak memory (MiB) a whole-suite run allocates (numpy arrays included: numpy reports its
    allocations to tracemalloc), per 1000 scenarios."""
    import tracemalloc

    from overtakezoo import zoo
    from overtakezoo.benchmark.run.runner import run_suite
    from overtakezoo.envs.suites import load_suite

    s = load_suite(suite)
    d = zoo.load(decider, config=s.config)
    tracemalloc.start()
    try:
        run_suite(s, d, progress=False)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    return round(peak / 2**20 / (s.count / 1000), 2)


def machine() -> dict[str, Any]:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return {
        "host": platform.node(),
        "cpu": cpu,
        "cores": os.cpu_count(),
        "os": platform.platform(),
        "python": platform.python_version(),
        "numpy": np.__version__,
    }


def load_average() -> list[float] | None:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return None


def highway_version() -> str | None:
    try:
        import highway_env  # noqa: F401  (registers two-way-v0 on import)
    except ImportError:
        return None
    import importlib.metadata as md

    return md.version("highway-env")


class Report:
    """Figures as rows with a stable id; ``add`` measures, prints a progress line and records."""

    def __init__(self, progress: Callable[[str], None]) -> None:
        self.rows: list[dict[str, Any]] = []
        self.progress = progress

    def add(
        self,
        id: str,
        what: str,
        unit: str,
        values: list[float],
        sim_s_per_unit: float | None = None,
        digits: int = 0,
        **extra: Any,
    ) -> dict[str, Any]:
        row = {
            "id": id,
            "what": what,
            "unit": unit,
            **spread([round(v, digits) if digits else round(v) for v in values]),
            **extra,
        }
        if sim_s_per_unit is not None:
            row["sim_s_per_wall_s"] = round(row["median"] * sim_s_per_unit, 1)
        self.rows.append(row)
        self.progress(f"{id:<28} {_fmt(row['median'])} {unit} (range {_fmt(row['min'])}-{_fmt(row['max'])})")
        return row

    def get(self, id: str) -> dict[str, Any] | None:
        return next((r for r in self.rows if r["id"] == id), None)

    def ratio(self, id: str, what: str, ours: str, theirs: str) -> None:
        a, b = self.get(ours), self.get(theirs)
        if a and b:
            value = round(a["sim_s_per_wall_s"] / b["sim_s_per_wall_s"], 1)
            self.rows.append(
                {"id": id, "what": what, "unit": "x (simulated s per wall s)", "median": value, "of": [ours, theirs]}
            )
            self.progress(f"{id:<28} {value}x")


def measure(
    sizes: list[int],
    seconds: float,
    repeats: int = 3,
    batch: int = 8,
    eval_runs: int = 5,
    suites: bool = True,
    progress: Callable[[str], None] = print,
    training: bool = True,
    only_training: bool = False,
    device: str | None = None,
    compile: bool = False,
) -> dict[str, Any]:
    """Every row of the report; with ``device`` (cuda, cuda:N, or cpu for the torch core on the
    CPU), the device rows instead (perf_device.py): the torch core beside the numpy core."""
    started = time.perf_counter()
    meta: dict[str, Any] = {
        "machine": machine(),
        "date": time.strftime("%Y-%m-%d %H:%M"),
        "load_average_at_start": load_average(),
        "repeats": repeats,
        "seconds_per_window": seconds,
    }
    r = Report(progress)
    if device is not None:
        from overtakezoo.benchmark.run.perf_device import add_device_rows

        add_device_rows(r, meta, sizes, seconds, repeats, device, compile)
    elif not only_training:
        _simulation_rows(r, meta, sizes, seconds, repeats, batch, eval_runs, suites, progress)
    if training and device is None:
        from overtakezoo.benchmark.run.perf_training import add_training_rows

        add_training_rows(r, repeats, progress)
    meta["load_average_at_end"] = load_average()
    meta["report_wall_time_s"] = round(time.perf_counter() - started, 1)
    return {**meta, "figures": r.rows}


def _simulation_rows(
    r: Report,
    meta: dict[str, Any],
    sizes: list[int],
    seconds: float,
    repeats: int,
    batch: int,
    eval_runs: int,
    suites: bool,
    progress: Callable[[str], None],
) -> None:
    """Every row but the training ones: the core, the faces, highway-env, table1 runs, archives."""
    dt = EnvConfig().dt
    for n in sizes:
        r.add(
            f"core-{n}",
            f"batched core, N = {n}, planner included",
            "env-steps/s",
            core_rates(n, seconds, repeats),
            dt,
            n=n,
        )
    r.add(
        "pettingzoo-1",
        "one PettingZoo parallel_env() (one ego, N = 1)",
        "steps/s",
        pettingzoo_rates(seconds, repeats),
        dt,
        n=1,
    )
    r.add(
        "gym-1",
        f"one Gymnasium env of ours, gymnasium.make({OUR_ID!r})",
        "steps/s",
        gym_rates(OUR_ID, OVERTAKE, seconds, repeats),
        dt,
        n=1,
    )
    r.add(
        f"gym-vec-{batch}",
        f"our gymnasium.make_vec batch, N = {batch} (one process)",
        "env-steps/s",
        vec_rates(OUR_ID, batch, None, OVERTAKE, seconds, repeats),
        dt,
        n=batch,
    )
    hw = highway_version()
    meta["highway_env"] = hw
    if hw:
        import gymnasium as gym

        per_decision = 1.0 / gym.make(HIGHWAY_ID).unwrapped.config["policy_frequency"]
        r.add(
            "highway-1",
            f"one highway-env {hw} {HIGHWAY_ID}, gymnasium.make",
            "steps/s",
            gym_rates(HIGHWAY_ID, HIGHWAY_IDLE, seconds, repeats),
            per_decision,
            digits=1,
            n=1,
        )
        for mode in ("sync", "async"):
            r.add(
                f"highway-vec-{mode}-{batch}",
                f"highway-env {HIGHWAY_ID} make_vec, N = {batch}, {mode}",
                "env-steps/s",
                vec_rates(HIGHWAY_ID, batch, mode, HIGHWAY_IDLE, seconds, repeats),
                per_decision,
                digits=1,
                n=batch,
            )
        r.ratio("ratio-1", "one env: ours (gym-1) / highway-env (highway-1)", "gym-1", "highway-1")
        for mode in ("sync", "async"):
            r.ratio(
                f"ratio-vec-{mode}-{batch}",
                f"batch of N = {batch}: ours (gym-vec-{batch}) / highway-env {mode} (highway-vec-{mode}-{batch})",
                f"gym-vec-{batch}",
                f"highway-vec-{mode}-{batch}",
            )
    else:
        progress("highway-env not installed (the [compare] extra): its rows are left out")
    if suites:
        for decider in ("rule-fsm", "dqn"):
            try:
                t = suite_wall_times("table1", decider, repeats)
            except Exception as exc:  # a member missing from this install is reported, not fatal
                progress(f"runner-table1-{decider}: not measured: {str(exc).splitlines()[0]}")
                continue
            r.add(
                f"runner-table1-{decider}",
                f"table1 ({t['scenarios']} scenarios) with {decider}, whole run in "
                "the runner (scenarios, decider, simulation; no process start-up)",
                "s",
                t["runs"],
                digits=2,
            )
        try:
            walls, cpus = eval_process_runs("table1", "dqn", eval_runs)
            r.add(
                "eval-table1-dqn",
                "`overtakezoo eval --suite table1 --decider dqn` as a process, start to exit "
                f"(median of {eval_runs} runs; start-up included; numpy inference, no torch)",
                "s",
                walls,
                digits=2,
            )
            r.add("eval-table1-dqn-cpu", "the same processes' user + sys CPU time", "s", cpus, digits=2)
        except RuntimeError as exc:
            progress(f"eval-table1-dqn: not measured: {exc}")
        r.add(
            "memory-table1",
            "peak memory of a table1 run (rule-fsm), per 1000 scenarios",
            "MiB",
            [peak_memory_per_1000_scenarios()],
            digits=2,
        )
        try:
            a = archive_costs()
            r.add(
                "archive-table1-1000",
                "MCAP archive of 1000 table1 episodes (rule-fsm, scene at every step)",
                "MB",
                [a["mb"]],
                digits=1,
            )
            r.add(
                "archive-cpu-ratio",
                "CPU time of that run with the archive / without it",
                "x",
                [a["cpu_ratio"]],
                digits=1,
            )
            r.add(
                "replay-gif-246",
                "`overtakezoo replay --episode 29 --out ep.gif` as a process, a 246-frame "
                f"episode (median of {repeats} runs; start-up included)",
                "s",
                replay_gif_times(repeats),
                digits=2,
            )
        except RuntimeError as exc:
            progress(f"archive and replay rows: not measured: {exc}")
        from overtakezoo.benchmark.failures.perf_rows import add_failure_search_rows  # failure search (issue 23)

        add_failure_search_rows(r, progress)


def _fmt(x: float) -> str:
    return f"{x:,.0f}" if abs(x) >= 100 else f"{x:,.2f}".rstrip("0").rstrip(".")


def to_markdown(report: dict[str, Any]) -> str:
    m = report["machine"]
    dev = report.get("device")
    on = (
        f" Device rows: torch {dev['torch']} on {dev['device']}"
        + (
            f" ({dev['gpu']}, {dev['gpu_memory_gib']} GiB, CUDA {dev['cuda']}, driver {dev['driver']})"
            if "gpu" in dev
            else ""
        )
        + "."
        if dev
        else ""
    )
    lines = [
        "# Performance report" + (f" on {dev['device']}" if dev else ""),
        "",
        f"Written by `overtakezoo perf` on {report['date']}: {m['cpu']}, {m['cores']} cores, {m['os']}, "
        f"Python {m['python']}, numpy {m['numpy']}, highway-env {report.get('highway_env') or 'not installed'}.{on}",
        f"Load average (1, 5, 15 min) {report['load_average_at_start']} at the start, "
        f"{report['load_average_at_end']} at the end. Each figure is the median of {report['repeats']} "
        f"windows of {report['seconds_per_window']} s (whole runs for the `runner-`, `eval-`, `train-` and "
        f"`time-to-` rows) with "
        f"the range; the report took {report['report_wall_time_s']} s.",
    ]
    loads = [x for key in ("load_average_at_start", "load_average_at_end") for x in (report[key] or [])[:1]]
    if loads and max(loads) > m["cores"]:
        lines.append(
            f"The machine was busy (load above its {m['cores']} cores): absolute figures are low; "
            "ratios of figures measured in this run are the robust part."
        )
    lines += ["", "| id | measurement | median | range | simulated s per wall s |", "|---|---|---|---|---|"]
    for row in report["figures"]:
        if "of" in row:  # a ratio of two rows' medians
            lines.append(f"| `{row['id']}` | {row['what']} | {row['median']}x | | |")
            continue
        rng = f"{_fmt(row['min'])} - {_fmt(row['max'])}" if len(row["runs"]) > 1 else ""
        sim = f"{row['sim_s_per_wall_s']:,.1f}" if "sim_s_per_wall_s" in row else ""
        lines.append(f"| `{row['id']}` | {row['what']} | {_fmt(row['median'])} {row['unit']} | {rng} | {sim} |")
    return "\n".join(lines) + "\n"


def write_report(report: dict[str, Any], out_prefix: str) -> None:
    from overtakezoo.envs.io import atomic_write_json, atomic_write_text

    atomic_write_json(out_prefix + ".json", report)
    atomic_write_text(out_prefix + ".md", to_markdown(report))


if __name__ == "__main__":
    from overtakezoo.benchmark.cli import main

    raise SystemExit(main(["perf", *sys.argv[1:]]))
