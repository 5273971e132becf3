"""Measure what the training guides quote and write it to docs/guides/figures.json.

Each guide's example runs as its slow test runs it, and the policy it trained is evaluated on table1
(the multi-agent guide's on duel).

    python scripts/guide_figures.py                    # every guide, cheapest first (about 20-30 min on 2 cores)
    python scripts/guide_figures.py --only sb3         # one guide, merged into the existing file

Per guide (docs/guides/<guide>.md, its slow test tests/docs/test_guide_<guide>.py or test_d3rlpy.py):
the example's command as the test writes it (same flags, seed 0, ``OMP_NUM_THREADS=1``, in a fresh
folder), its training time (wall and CPU) and decisions (or gradient steps) per second, then
``overtakezoo eval --suite table1`` on the file it wrote: success, crash and timeout rates with their
95 % intervals, and the same on table1-train, the split the settings were checked on (torchrl's
multi-agent guide: duel and duel-train, with the joint rates per road). Extras: sb3's
torch-thread comparison (a short run at 1, 2 and 8 threads) and the env's own decisions per second;
d3rlpy's run happens in a venv of its own (d3rlpy pins gymnasium 1.0, as test_d3rlpy.py builds it,
or ``--venv``) and also trains the slow test's 300 steps. Each guide's entry names its date, the
machine and the load; the file is rewritten after each guide, so an interrupted run keeps what it
measured. Needs the extras the guides install (``.[sb3]``, ``.[train,onnx]``; d3rlpy: PyPI or a venv).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
OUT = ROOT / "docs" / "guides" / "figures.json"
GUIDES = ("cleanrl", "rsl-rl", "sb3", "d3rlpy", "torchrl")  # cheapest first
NEEDS = {  # modules each guide's example imports in this interpreter, and the extra that installs them
    "cleanrl": (("torch", "onnx", "onnxruntime"), ".[train,onnx]"),
    "rsl-rl": (("torch", "rsl_rl", "onnx", "onnxruntime"), ".[train,onnx]"),
    "sb3": (("torch", "stable_baselines3"), ".[sb3]"),
    "d3rlpy": ((), "a venv with .[data,onnx,d3rlpy] (built here, or --venv)"),
    "torchrl": (("torch", "torchrl", "onnx", "onnxruntime"), ".[torchrl]"),
}
SB3_THREADS = (1, 2, 8)  # the thread comparison's settings
SB3_THREAD_STEPS = 6000
ENV_ID = "overtakezoo/table1-train-v2"
D3RLPY_STEPS = (20_000, 300)  # the guide's command, the slow test's run
DATASET = "overtakezoo/table1/rule-fsm-v0"


class FigureError(RuntimeError):
    """A guide could not be measured: the message says which command and why."""


def child_env(**extra: str) -> dict[str, str]:
    return dict(os.environ, OMP_NUM_THREADS="1", **extra)


def run(guide: str, command: list[str], cwd: Path, env: dict[str, str]) -> dict[str, Any]:
    """Run ``command`` in ``cwd``; its stdout, wall seconds and CPU seconds (its whole process tree)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        tail = (done.stdout[-2000:] + "\n" + done.stderr[-3000:]).strip()
        raise FigureError(f"{guide}: `{' '.join(map(str, command))}` exited {done.returncode} in {cwd}:\n{tail}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"stdout": done.stdout, "wall_s": round(wall, 1), "cpu_s": round(cpu, 1)}


def cli(python: Path) -> list[str]:
    """The ``overtakezoo`` command of the interpreter ``python`` (its installed script when there is one)."""
    script = python.with_name("overtakezoo")
    if script.is_file():
        return [str(script)]
    return [str(python), "-c", "import sys; from overtakezoo.benchmark.cli import main; sys.exit(main())"]


def evaluate(guide: str, python: Path, policy: Path, suite: str, cwd: Path, env: dict[str, str]) -> dict[str, Any]:
    """``overtakezoo eval --suite SUITE --policy POLICY``: its rates (value, 95 % interval, n)."""
    out = cwd / f"{suite}.json"
    done = run(
        guide,
        [*cli(python), "eval", "--suite", suite, "--policy", str(policy), "--out", str(out), "--no-progress"],
        cwd,
        env,
    )
    summary = json.loads(out.read_text())["summary"]
    rates = {}
    for key in ("success_rate", "crash_rate", "timeout_rate"):
        s = summary[key]
        rates[key] = s["value"]
        rates[key.replace("_rate", "_ci")] = [s["lo"], s["hi"]]
    for key in ("all_succeed", "any_crash", "av_crash"):  # multi-AV suites: per road (roads in joint_n)
        if key in summary.get("joint", {}):
            s = summary["joint"][key]
            rates[f"joint_{key}"], rates[f"joint_{key}_ci"], rates["joint_n"] = s["value"], [s["lo"], s["hi"]], s["n"]
    return {**rates, "n": summary["success_rate"]["n"], "eval_wall_s": done["wall_s"]}


def evaluations(guide: str, policy: Path, cwd: Path, suites: tuple[str, ...]) -> dict[str, dict[str, Any]]:
    """``evaluate`` on each suite with this interpreter, keyed as figures.json keys them (table1_train)."""
    return {
        suite.replace("-", "_"): evaluate(guide, Path(sys.executable), policy, suite, cwd, child_env())
        for suite in suites
    }


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def minutes(seconds: float) -> float:
    return round(seconds / 60, 2)


def train_figures(
    train_wall_s: float, train_cpu_s: float | None, decisions: int, script: dict[str, Any]
) -> dict[str, Any]:
    figures = {
        "decisions": decisions,
        "train_wall_min": minutes(train_wall_s),
        "decisions_per_s": round(decisions / train_wall_s, 1),
        "script_wall_min": minutes(script["wall_s"]),
        "script_cpu_min": minutes(script["cpu_s"]),
    }
    if train_cpu_s is not None:
        figures["train_cpu_min"] = minutes(train_cpu_s)
    return figures


def guide_cleanrl(work: Path) -> dict[str, Any]:
    command = [sys.executable, str(EXAMPLES / "cleanrl_ppo.py"), "--seed", "0", "--out", "runs/cleanrl-ppo"]
    script = run("cleanrl", command, work, child_env())
    folder = work / "runs" / "cleanrl-ppo"
    train = json.loads((folder / "train.json").read_text())
    policy = folder / "policy.onnx"
    return {
        "command": "python examples/cleanrl_ppo.py --seed 0 --out runs/cleanrl-ppo",
        "iterations": train["decisions"] // (train["args"]["num_envs"] * train["args"]["num_steps"]),
        **train_figures(train["train_wall_s"], None, train["decisions"], script),
        "policy_sha256": sha256(policy),
        **evaluations("cleanrl", policy, folder, ("table1", "table1-train")),
    }


def guide_rsl_rl(work: Path) -> dict[str, Any]:
    iterations = 60
    command = [
        sys.executable,
        str(EXAMPLES / "rsl_rl_ppo.py"),
        "--iterations",
        str(iterations),
        "--seed",
        "0",
        "--out",
        "runs/rsl-ppo",
    ]
    script = run("rsl-rl", command, work, child_env())
    # The example writes no train.json: its last progress line says the seconds spent training.
    lines = re.findall(rf"^iteration {iterations}/{iterations}\s+(\d+) s", script["stdout"], re.M)
    if not lines:
        raise FigureError(f"rsl-rl: no 'iteration {iterations}/{iterations}  N s' line in the example's output")
    folder = work / "runs" / "rsl-ppo"
    policy = folder / "policy.onnx"
    return {
        "command": f"python examples/rsl_rl_ppo.py --iterations {iterations} --seed 0 --out runs/rsl-ppo",
        "iterations": iterations,
        **train_figures(float(lines[-1]), None, iterations * 256 * 32, script),
        "policy_sha256": sha256(policy),
        **evaluations("rsl-rl", policy, folder, ("table1", "table1-train")),
    }


def guide_torchrl(work: Path) -> dict[str, Any]:
    """The multi-agent guide: trained on duel-train, so evaluated on duel (joint success per road)."""
    command = [sys.executable, str(EXAMPLES / "torchrl_marl.py"), "--seed", "0", "--out", "runs/torchrl"]
    script = run("torchrl", command, work, child_env())
    folder = work / "runs" / "torchrl"
    train = json.loads((folder / "train.json").read_text())
    policy = folder / "policy.onnx"
    return {
        "command": "python examples/torchrl_marl.py --seed 0 --out runs/torchrl",
        "frames": train["frames"],
        "updates": train["updates"],
        **train_figures(train["train_wall_s"], None, train["decisions"], script),
        "policy_sha256": sha256(policy),
        **evaluations("torchrl", policy, folder, ("duel", "duel-train")),
    }


def env_decisions_per_s(decisions: int = 3000) -> float:
    """One ``overtakezoo/table1-train-v2`` env stepped with random actions: decisions (env steps) per second."""
    import gymnasium as gym

    import overtakezoo.envs  # noqa: F401  registers the ids

    env = gym.make(ENV_ID)
    env.action_space.seed(0)
    env.reset(seed=0)
    t0 = time.perf_counter()
    for _ in range(decisions):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()
    rate = decisions / (time.perf_counter() - t0)
    env.close()
    return round(rate, 1)


def guide_sb3(work: Path) -> dict[str, Any]:
    steps = 60_000
    example = str(EXAMPLES / "sb3_dqn.py")
    command = [sys.executable, example, "--steps", str(steps), "--seed", "0", "--out", "."]
    script = run("sb3", command, work, child_env())
    train = json.loads((work / "train.json").read_text())
    policy = work / "model.zip"
    figures = {
        "command": f"python examples/sb3_dqn.py --steps {steps} --seed 0 --out runs/sb3-dqn",
        **train_figures(train["train_wall_s"], train["train_cpu_s"], steps, script),
        "policy_sha256": sha256(policy),
        **evaluations("sb3", policy, work, ("table1", "table1-train")),
    }
    study = []
    for threads in SB3_THREADS:
        folder = work / f"threads-{threads}"
        folder.mkdir(exist_ok=True)
        short = [sys.executable, example, "--steps", str(SB3_THREAD_STEPS), "--seed", "0", "--out", "."]
        run("sb3", [*short, "--threads", str(threads)], folder, dict(os.environ))  # torch's own threads
        short_train = json.loads((folder / "train.json").read_text())
        study.append({"threads": threads, "steps": SB3_THREAD_STEPS, "steps_per_s": short_train["steps_per_s"]})
    figures["threads_study"] = study
    figures["env_decisions_per_s"] = env_decisions_per_s()
    return figures


def d3rlpy_venv(venv: Path | None, work: Path) -> tuple[Path, float | None]:
    """The python of a venv with overtakezoo[data,onnx,d3rlpy] and torch 2.13.0 (built as
    tests/docs/test_d3rlpy.py builds it when ``venv`` is None or empty); its build minutes."""
    venv = venv or work / "venv"
    python = venv / "bin" / "python"
    if python.is_file():
        return python, None
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env.update(PIP_CACHE_DIR=str(work / "pip-cache"), PIP_DISABLE_PIP_VERSION_CHECK="1")
    build = run("d3rlpy", [sys.executable, "-m", "venv", str(venv)], work, env)
    install = run(
        "d3rlpy",
        [str(python), "-m", "pip", "install", "-q", f"{ROOT}[data,onnx,d3rlpy]", "torch==2.13.0"],
        work,
        env,
    )
    return python, minutes(build["wall_s"] + install["wall_s"])


def guide_d3rlpy(work: Path, venv: Path | None) -> dict[str, Any]:
    python, build_min = d3rlpy_venv(venv, work)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["OMP_NUM_THREADS"] = "1"
    if "MINARI_DATASETS_PATH" not in env:  # the dataset (fetched or rebuilt once) stays in the work folder
        env.update(MINARI_DATASETS_PATH=str(work / "datasets"), OVERTAKEZOO_HOME=str(work / "home"))
    versions = run(
        "d3rlpy",
        [
            str(python),
            "-c",
            "import d3rlpy, gymnasium, torch; print(d3rlpy.__version__, gymnasium.__version__, torch.__version__)",
        ],
        work,
        env,
    )["stdout"].split()
    figures: dict[str, Any] = {"d3rlpy": versions[0], "gymnasium": versions[1], "torch": versions[2]}
    if build_min is not None:
        figures["venv_build_min"] = build_min
    registry = json.loads((ROOT / "benchmark" / "datasets" / "registry" / "datasets.json").read_text())
    data = registry["datasets"][DATASET]
    figures["dataset"] = {
        "name": DATASET,
        "transitions": data["steps"],
        **{f"{k}_rate": v for k, v in data["outcomes"].items()},
    }
    runs = []
    for steps in D3RLPY_STEPS:
        folder = work / f"cql-{steps}"
        folder.mkdir(exist_ok=True)
        command = [str(python), str(EXAMPLES / "d3rlpy_cql.py"), "--steps", str(steps), "--seed", "0", "--out", "."]
        script = run("d3rlpy", command, folder, env)
        train = json.loads((folder / "train.json").read_text())
        policy = folder / "policy.onnx"
        runs.append(
            {
                "steps": steps,
                "command": f"python examples/d3rlpy_cql.py --steps {steps} --seed 0 --out runs/d3rlpy-cql",
                "transitions": train["transitions"],
                "train_wall_min": minutes(train["train_wall_s"]),
                "train_cpu_min": minutes(train["train_cpu_s"]),
                "steps_per_s": train["steps_per_s"],
                "script_wall_min": minutes(script["wall_s"]),
                "policy_sha256": sha256(policy),
                "table1": evaluate("d3rlpy", python, policy, "table1", folder, env),
            }
        )
    figures["runs"] = runs
    return figures


def measure(guide: str, work: Path, venv: Path | None) -> dict[str, Any]:
    from overtakezoo.benchmark.run.perf import load_average, machine

    modules, extra = NEEDS[guide]
    for module in modules:
        try:
            __import__(module)
        except ImportError:
            raise FigureError(f"{guide}: needs {module!r} (pip install -e '{extra}')") from None
    folder = work / guide
    folder.mkdir(parents=True, exist_ok=True)
    started = {"date": time.strftime("%Y-%m-%d %H:%M"), "machine": machine(), "load_average_at_start": load_average()}
    print(f"{guide}: measuring in {folder} ...", file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    if guide == "cleanrl":
        figures = guide_cleanrl(folder)
    elif guide == "rsl-rl":
        figures = guide_rsl_rl(folder)
    elif guide == "sb3":
        figures = guide_sb3(folder)
    elif guide == "torchrl":
        figures = guide_torchrl(folder)
    else:
        figures = guide_d3rlpy(folder, venv)
    if guide != "d3rlpy":
        import torch

        figures["torch"] = torch.__version__
    return {
        **started,
        "load_average_at_end": load_average(),
        "wall_min": minutes(time.perf_counter() - t0),
        "seed": 0,
        "threads": 1,
        **figures,
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", choices=GUIDES, action="append", help="measure this guide only (repeatable)")
    p.add_argument("--out", type=Path, default=OUT, help=f"figures file (default {OUT.relative_to(ROOT)})")
    p.add_argument("--work", type=Path, help="folder for the runs (kept); default a temporary one, removed")
    p.add_argument("--venv", type=Path, help="d3rlpy: a venv to use (built there when it has no python)")
    args = p.parse_args(argv)

    from overtakezoo.benchmark.run.perf import machine
    from overtakezoo.envs.io import atomic_write_json, check_writable

    check_writable(args.out)
    doc: dict[str, Any] = {"guides": {}}
    if args.out.is_file():
        doc = json.loads(args.out.read_text())
        doc.setdefault("guides", {})
    with tempfile.TemporaryDirectory(prefix="guide-figures-") as tmp:
        work = args.work or Path(tmp)
        for guide in args.only or GUIDES:
            try:
                figures = measure(guide, work, args.venv)
            except FigureError as exc:
                print(f"guide_figures: {exc}", file=sys.stderr)
                return 1
            doc["guides"][guide] = figures
            doc.update(
                generated_by="python scripts/guide_figures.py",
                date=figures["date"],
                machine={k: v for k, v in machine().items() if k in ("cpu", "cores", "os", "python")},
            )
            atomic_write_json(args.out, doc)
            suite = "duel" if "duel" in figures else "table1"
            rates = figures.get(suite) or figures["runs"][0]["table1"]
            print(
                f"{guide}: {figures['wall_min']} min; {suite} success {rates['success_rate']:.3f}, "
                f"crash {rates['crash_rate']:.3f}; wrote {args.out}",
                file=sys.stderr,
                flush=True,
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
