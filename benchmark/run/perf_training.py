"""The training rows of the performance report (``overtakezoo perf``; benchmark/run/perf.py).

Two PPO trainers side by side: the numpy PPO (``overtakezoo train ppo-numpy``,
:mod:`overtakezoo.zoo.train.fastppo` with ``zoo/hyperparams/ppo-numpy.toml``, no torch) and rsl-rl's
``OnPolicyRunner`` (``overtakezoo train ppo``: ``zoo/train/ppo.py`` with ``zoo/hyperparams/ppo.toml``,
what the shipped ppo member was trained with).

- ``train-throughput-core-train`` (numpy PPO, ``--set env.num_envs=`` :data:`FAST_THROUGHPUT_ENVS`)
  and ``train-throughput-core-train-rsl-rl``: env-steps (core steps: decisions x the 1 s hold) per
  CPU second of ``overtakezoo train ppo-numpy | ppo --suite core-train --eval-suite none`` for a fixed budget,
  as a process (imports, model selection and outputs included), and the same per wall second.
- ``time-to-paper-level`` (numpy PPO) and ``time-to-paper-level-rsl-rl``: from scratch on
  ``table1-train`` to the paper's DQN figure on ``table1`` (success >= 92.2 %, crash <= 5 %). Per
  seed, the training process ``overtakezoo train ppo-numpy | ppo --suite table1-train --eval-suite none`` is run
  at the budgets of its ladder in turn; the shipped policy of each is then evaluated on table1 by a
  separate ``overtakezoo eval --policy`` process (the yardstick, not part of training; its time is
  in the ``-with-eval`` row); the seed's figure is the time of the first training process whose
  policy reaches the level (``inf``: none did). The median is over :data:`SEEDS`. Nothing is chosen
  from these runs: table1 is only the yardstick the figure is defined by.
- ``time-to-zoo-quality``: a zoo member at its leaderboard quality from ``core-train``: the numpy
  PPO on the whole mixture (:data:`ZOO_ARGS`) at the budgets of :data:`ZOO_LADDER` in turn, until
  its policy's leaderboard score (success - 2 x crash, mean over the nine splits) on each split's
  held-back scenarios (from :data:`HELD_BACK` on; model selection scored the first ones) is at least
  the shipped ppo member's on the same scenarios. Both are scored as the leaderboard runs them: the
  shipped member with its card's decision rate and OVERTAKE threshold, the new run with the same two
  (:data:`DEPLOYED`, the member's recipe: chosen once on the training splits, not per run).
  Training splits only: no test suite is read.
"""

from __future__ import annotations

import json
import math
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

SEEDS = (0, 1, 2)
PAPER_SUCCESS, PAPER_CRASH = 0.922, 0.05
HOLD = 10  # core steps per decision (both hyperparameter files' action_repeat)
FAST, RSL = "ppo-numpy", "ppo"  # the two trainers' names (`overtakezoo train NAME`, their own hyperparameter files)
FAST_STEPS_PER_ENV = 4  # ppo-numpy.toml: num_steps_per_env
FAST_ITERATION = 512 * FAST_STEPS_PER_ENV  # decisions per iteration (ppo-numpy.toml: num_envs x num_steps_per_env)
FAST_LADDER = (8, 12, 16, 24, 32)  # iterations tried in turn
FAST_THROUGHPUT_ENVS = 4096  # rows on core-train (9 suites): the core's cost per row falls with the batch
FAST_THROUGHPUT_ITERATIONS = 8
RSL_ITERATION = 256 * 32  # ppo.toml: num_envs x num_steps_per_env
RSL_LADDER = (4, 8, 16, 32, 64)
THROUGHPUT_ITERATIONS = 8  # rsl-rl
ZOO_ARGS = ["--set", f"env.num_envs={FAST_THROUGHPUT_ENVS}", "--set", "train.select_every=8"]  # (FAST)
ZOO_ITERATION = FAST_THROUGHPUT_ENVS * FAST_STEPS_PER_ENV  # decisions per iteration on core-train
ZOO_LADDER = (30, 60, 90)  # 60 iterations: ~1M decisions, the shipped ppo's budget
HELD_BACK = 500  # each core-train split's scenarios from here on are the yardstick
DEPLOYED = ("decide_every", "overtake_offset")  # the shipped card's deployment settings a new run is scored with


def _train(trainer: str, args: list[str], tmp: str) -> tuple[float, float, Path]:
    from overtakezoo.benchmark.run.perf import _cli

    out = Path(tmp) / f"run{len(list(Path(tmp).iterdir()))}"
    wall, cpu = _cli(["train", trainer, *args, "--eval-suite", "none", "--out", str(out)], tmp)
    return wall, cpu, out


def _paper_level(trainer: str, out: Path, tmp: str) -> tuple[bool, str, float, float]:
    """Evaluate the run's shipped policy on table1 in its own process: (reached, summary, wall, CPU)."""
    from overtakezoo.benchmark.run.perf import _cli

    results = out / "table1.results.json"
    wall, cpu = _cli(
        ["eval", "--suite", "table1", "--policy", str(out / f"{trainer}.npz"), "--out", str(results), "--no-safety"],
        tmp,
    )
    summary = json.loads(results.read_text())["summary"]
    success, crash = summary["success_rate"]["value"], summary["crash_rate"]["value"]
    return (
        success >= PAPER_SUCCESS and crash <= PAPER_CRASH,
        f"{100 * success:.1f} % / {100 * crash:.1f} %",
        wall,
        cpu,
    )


def _shown(args: list[str]) -> str:
    return "".join(f" {a}" for a in args)


def _throughput(report: Any, trainers: list[tuple[str, str, str, list[str], int]], repeats: int, tmp: str) -> None:
    """``trainers``: (row, who, trainer, extra args, decisions); their processes interleaved (A B A B
    ...), so a change in the machine's load falls on both alike."""
    runs: dict[str, list[tuple[float, float]]] = {row: [] for row, *_ in trainers}
    for s in range(repeats):
        for row, _, trainer, args, steps in trainers:
            wall, cpu, _ = _train(
                trainer, ["--suite", "core-train", "--steps", str(steps), "--seed", str(s), *args], tmp
            )
            runs[row].append((wall, cpu))
    for row, who, trainer, args, steps in trainers:
        report.add(
            row,
            f"{who}: `overtakezoo train {trainer} --suite core-train --eval-suite none{_shown(args)}`, "
            f"{steps} decisions as a process: env-steps (decisions x {HOLD}) per CPU second (interleaved "
            f"with the other trainer's runs)",
            "env-steps/s",
            [steps * HOLD / cpu for _, cpu in runs[row]],
        )
        report.add(
            f"{row}-wall",
            "the same processes, env-steps per wall second",
            "env-steps/s",
            [steps * HOLD / wall for wall, _ in runs[row]],
        )


def _ladder(
    ladder: tuple[int, ...], attempt: Callable[[int, int], tuple[bool, float, float, float, str]]
) -> tuple[list[float], list[float], list[float], list[str]]:
    """Per seed, the budgets of ``ladder`` in turn until ``attempt(seed, k)`` -> (reached, wall, CPU,
    extra wall, note) gets there: the walls, CPU times and walls plus extra of the first that does
    (``inf`` where none does), and a note per seed."""
    walls, cpus, totals, reached = [], [], [], []
    for seed in SEEDS:
        wall = cpu = total = math.inf
        for k in ladder:
            ok, w, c, extra, note = attempt(seed, k)
            if ok:
                wall, cpu, total = w, c, w + extra
                reached.append(f"seed {seed}: {k} iterations ({note})")
                break
        else:
            reached.append(f"seed {seed}: not within {ladder[-1]} iterations")
        walls.append(wall)
        cpus.append(cpu)
        totals.append(total)
    return walls, cpus, totals, reached


def _time_to_level(
    report: Any,
    row: str,
    who: str,
    trainer: str,
    args: list[str],
    iteration: int,
    ladder: tuple[int, ...],
    tmp: str,
    progress: Callable[[str], None],
) -> None:
    def attempt(seed: int, k: int) -> tuple[bool, float, float, float, str]:
        w, c, out = _train(
            trainer, ["--suite", "table1-train", "--steps", str(k * iteration), "--seed", str(seed), *args], tmp
        )
        ok, summary, ew, _ = _paper_level(trainer, out, tmp)
        progress(f"{row}: seed {seed}, {k} iterations: {w:.2f} s wall, {c:.2f} s CPU; table1 {summary}")
        return ok, w, c, ew, f"{summary}, {w:.2f} s"

    walls, cpus, with_eval, reached = _ladder(ladder, attempt)
    what = (
        f"{who}: from scratch on table1-train to >= 92.2 % success and <= 5 % crash on table1; the training "
        f"process `overtakezoo train {trainer} --suite table1-train --eval-suite none{_shown(args)}` at "
        f"{', '.join(map(str, ladder))} iterations ({iteration} decisions each) in turn, the first whose "
        f"policy gets there ({'; '.join(reached)}); median of {len(SEEDS)} seeds"
    )
    report.add(row, what + ", wall time of the training process", "s", walls, digits=2)
    report.add(f"{row}-cpu", "the same processes' user + sys CPU time", "s", cpus, digits=2)
    report.add(
        f"{row}-with-eval",
        "the same plus the `overtakezoo eval --suite table1 --policy` process that checks it, wall",
        "s",
        with_eval,
        digits=2,
    )


def _held_back_score(decider: Any, sets: list) -> float:
    """Success - K x crash, mean over ``sets``, each decision held as the member is deployed."""
    from overtakezoo.benchmark.leaderboard.headline import K
    from overtakezoo.zoo.train.selection import decider_act, outcome_rates

    rates = outcome_rates(decider_act(decider), sets, decider.action_repeat)
    return float(sum(s - K * c for s, c in rates) / len(sets))


def _recipe(recipe: dict[str, Any]) -> str:
    shown = {"decide_every": "decision every {} core steps", "overtake_offset": "{:+g} on the OVERTAKE score"}
    return ", ".join(shown[k].format(v) for k, v in recipe.items()) or "training hold and no threshold"


def _time_to_zoo_quality(report: Any, tmp: str, progress: Callable[[str], None]) -> None:
    from overtakezoo.benchmark.suite_groups import load_training
    from overtakezoo.zoo.members.learned import MLPDecider, load_pretrained, load_weights, read_card
    from overtakezoo.zoo.train.selection import held_back_sets

    suites = load_training("core-train")
    sets = held_back_sets(suites, HELD_BACK)
    shipped = load_pretrained("ppo", suites[0].config)
    recipe = {k: shipped.model_card[k] for k in DEPLOYED if k in shipped.model_card}
    target = _held_back_score(shipped, sets)

    def attempt(seed: int, k: int) -> tuple[bool, float, float, float, str]:
        w, c, out = _train(
            FAST, ["--suite", "core-train", "--steps", str(k * ZOO_ITERATION), "--seed", str(seed), *ZOO_ARGS], tmp
        )
        card = {**read_card(out / f"{FAST}.json", FAST), **recipe}
        got = _held_back_score(MLPDecider(load_weights(out / f"{FAST}.npz", card), FAST, suites[0].config, card), sets)
        progress(
            f"time-to-zoo-quality: seed {seed}, {k} iterations: {w:.2f} s wall, {c:.2f} s CPU; "
            f"held-back score {100 * got:.1f} (shipped ppo {100 * target:.1f})"
        )
        return got >= target, w, c, 0.0, f"{100 * got:.1f}, {c:.1f} CPU s"

    walls, cpus, _, reached = _ladder(ZOO_LADDER, attempt)
    what = (
        f"numpy PPO from scratch on core-train to the shipped ppo member's leaderboard score (success - 2 x "
        f"crash, mean over the 9 splits) on every split's held-back training scenarios {HELD_BACK}-999 "
        f"({100 * target:.1f}), both deployed with the shipped card's {_recipe(recipe)}; the process "
        f"`overtakezoo train {FAST} --suite core-train --eval-suite none"
        f"{_shown(ZOO_ARGS)}` at {', '.join(map(str, ZOO_LADDER))} iterations ({ZOO_ITERATION} decisions each) "
        f"in turn, the first that gets there ({'; '.join(reached)}); median of {len(SEEDS)} seeds, user + sys "
        "CPU time of the training process"
    )
    report.add("time-to-zoo-quality", what, "s", cpus, digits=1)
    report.add("time-to-zoo-quality-wall", "the same processes, wall", "s", walls, digits=1)


def add_training_rows(report: Any, repeats: int = 3, progress: Callable[[str], None] = print) -> None:
    try:
        import torch  # noqa: F401  (the [train] extra: rsl-rl)

        rsl_rl = True
    except ImportError:
        progress("rsl-rl rows: not measured: torch is not installed (pip install -e '.[train]')")
        rsl_rl = False
    fast, rsl = "numpy PPO (zoo/train/fastppo.py)", "rsl-rl PPO (zoo/train/ppo.py, ppo.toml)"
    with tempfile.TemporaryDirectory() as tmp:
        trainers = [
            (
                "train-throughput-core-train",
                fast,
                FAST,
                ["--set", f"env.num_envs={FAST_THROUGHPUT_ENVS}"],
                FAST_THROUGHPUT_ITERATIONS * FAST_THROUGHPUT_ENVS * FAST_STEPS_PER_ENV,
            )
        ]
        if rsl_rl:
            trainers.append(("train-throughput-core-train-rsl-rl", rsl, RSL, [], THROUGHPUT_ITERATIONS * RSL_ITERATION))
        _throughput(report, trainers, repeats, tmp)
        _time_to_level(report, "time-to-paper-level", fast, FAST, [], FAST_ITERATION, FAST_LADDER, tmp, progress)
        if rsl_rl:
            _time_to_level(report, "time-to-paper-level-rsl-rl", rsl, RSL, [], RSL_ITERATION, RSL_LADDER, tmp, progress)
        _time_to_zoo_quality(report, tmp, progress)
