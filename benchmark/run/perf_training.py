"""The training rows of the performance report (``overtakezoo perf``; benchmark/run/perf.py).

- ``train-throughput-core-train``: env-steps (core steps: decisions x the 1 s hold) per CPU second of
  ``overtakezoo train ppo --suite core-train`` for a fixed budget, as a process (imports, the
  trainer's model selection and checkpoints included; no final eval), and the same per wall second.
- ``time-to-paper-level``: from scratch on ``table1-train`` to the paper's DQN figure on ``table1``
  (success >= 92.2 %, crash <= 5 %). Per seed, ``overtakezoo train ppo --suite table1-train
  --eval-suite table1`` is run as a whole process at the budgets of :data:`LADDER` in turn; the
  seed's figure is the wall (and CPU) time of the first process whose shipped policy reaches the
  level (``inf``: none did). The median is over :data:`SEEDS`. Nothing is chosen from these runs:
  table1 is only the yardstick the figure is defined by.

The trainer is ppo through rsl-rl's ``OnPolicyRunner`` (``zoo/train/ppo.py``), the zoo's fastest.
"""

from __future__ import annotations

import json
import math
import tempfile
from pathlib import Path
from typing import Any, Callable

SEEDS = (0, 1, 2)
ITERATION = 256 * 32  # decisions per ppo iteration (zoo/hyperparams/ppo.toml: num_envs x num_steps_per_env)
LADDER = (4, 8, 16, 32, 64)  # iterations tried in turn
THROUGHPUT_ITERATIONS = 8
HOLD = 10  # core steps per decision (ppo.toml action_repeat)
PAPER_SUCCESS, PAPER_CRASH = 0.922, 0.05


def _train(args: list[str], tmp: str) -> tuple[float, float, dict[str, Any]]:
    from overtakezoo.benchmark.run.perf import _cli

    out = Path(tmp) / f"run{len(list(Path(tmp).iterdir()))}"
    wall, cpu = _cli(["train", "ppo", *args, "--out", str(out)], tmp)
    return wall, cpu, json.loads((out / "ppo.json").read_text())


def add_training_rows(report: Any, repeats: int = 3, progress: Callable[[str], None] = print) -> None:
    try:
        import torch  # noqa: F401  (the [train] extra)
    except ImportError:
        progress("training rows: not measured: torch is not installed (pip install -e '.[train]')")
        return
    with tempfile.TemporaryDirectory() as tmp:
        steps = THROUGHPUT_ITERATIONS * ITERATION
        runs = [_train(["--suite", "core-train", "--steps", str(steps), "--seed", str(s), "--eval-suite", "none"], tmp)
                for s in range(repeats)]
        report.add("train-throughput-core-train", f"`overtakezoo train ppo --suite core-train`, {steps} decisions "
                   f"({THROUGHPUT_ITERATIONS} iterations) as a process: env-steps (decisions x {HOLD}) per CPU second",
                   "env-steps/s", [steps * HOLD / cpu for _, cpu, _ in runs])
        report.add("train-throughput-core-train-wall", "the same processes, env-steps per wall second", "env-steps/s",
                   [steps * HOLD / wall for wall, _, _ in runs])
        walls, cpus, reached = [], [], []
        for seed in SEEDS:
            wall = cpu = math.inf
            for k in LADDER:
                w, c, card = _train(["--suite", "table1-train", "--steps", str(k * ITERATION), "--seed", str(seed),
                                     "--eval-suite", "table1"], tmp)
                res = card["results"]["table1"]
                if res["success_rate"] >= PAPER_SUCCESS and res["crash_rate"] <= PAPER_CRASH:
                    wall, cpu = w, c
                    reached.append(f"seed {seed}: {k} iterations ({100 * res['success_rate']:.1f} % / "
                                   f"{100 * res['crash_rate']:.1f} %)")
                    break
            else:
                reached.append(f"seed {seed}: not within {LADDER[-1]} iterations")
            walls.append(wall)
            cpus.append(cpu)
        what = ("from scratch on table1-train to >= 92.2 % success and <= 5 % crash on table1, "
                "`overtakezoo train ppo --suite table1-train --eval-suite table1` as a whole process at "
                f"{', '.join(map(str, LADDER))} iterations in turn, the first that gets there "
                f"({'; '.join(reached)}); median of {len(SEEDS)} seeds")
        report.add("time-to-paper-level", what + ", wall time", "s", walls, digits=2)
        report.add("time-to-paper-level-cpu", "the same processes' user + sys CPU time", "s", cpus, digits=2)
