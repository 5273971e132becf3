"""Training, orchestrated: what ``overtakezoo train`` does around a zoo trainer.

The trainers (``overtakezoo.zoo.train``: dqn, ppo, bc, cql) take what they learn from already
loaded and return the trained member (a ``Trained``: model card, weights, the numpy network that
ships); they know nothing of the benchmark. Here, for every trainer alike, :func:`train`

1. asks the zoo's registry which trainer trains the member, and the trainer what it learns from;
2. loads it: the training suites (``overtakezoo.benchmark.suite_groups.load_training``) or a dataset of the
   benchmark's registry (:mod:`.datasets`, with its content hash);
3. calls the trainer (which writes its log, checkpoints and outputs into ``out``);
4. evaluates what ships, the numpy network, on ``eval_suite`` with the benchmark runner, records
   the outcome in the card (``results[<suite>]``), writes the card again and the runner's results
   file ``<member>-<suite>.results.json`` beside it, ready for ``overtakezoo submit``.
"""

from __future__ import annotations

import importlib
import importlib.util
from pathlib import Path
from typing import Any

import numpy as np

from overtakezoo import zoo
from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.results.metrics import wilson
from overtakezoo.benchmark.run.runner import run_suite
from overtakezoo.benchmark.suite_groups import load_training
from overtakezoo.envs import CRASH, SUCCESS, TIMEOUT
from overtakezoo.envs.config import ConfigError
from overtakezoo.envs.suites import Suite, load_suite


def trainer(member: str) -> Any:
    """The module under ``overtakezoo.zoo.train`` that trains ``member`` (the registry says which), or
    the trainer of that name that is not a member (``ppo-numpy``: ``zoo.train.contract.TRAINERS``)."""
    from overtakezoo.zoo.train.contract import TRAINERS

    if member in TRAINERS:
        module = TRAINERS[member][0]
    else:
        try:
            entry = zoo.member(member)
        except zoo.UnknownDecider as exc:
            raise UserError(str(exc)) from None
        if entry.kind != "learned" or not entry.trainer:
            raise UserError(
                f"{member} is a {entry.kind} member, not trained (learned members: "
                f"{', '.join(zoo.names('learned'))}; trainers of their own: {', '.join(TRAINERS)})"
            )
        module = entry.trainer
    try:
        return importlib.import_module(f"overtakezoo.zoo.train.{module}")
    except ModuleNotFoundError as exc:
        if (exc.name or "").startswith("overtakezoo"):
            raise
        raise UserError(f"training {member} needs {exc.name} (pip install -e '.[train]')") from None


def train(
    member: str,
    *,
    suite: str = "table1-train",
    dataset: str | None = None,
    steps: int | None = None,
    seed: int | None = None,
    out: str | Path | None = None,
    resume: str | Path | None = None,
    hyperparams: str | Path | None = None,
    overrides: dict[str, Any] | None = None,
    eval_suite: str | None = "table1",
    progress: bool = True,
    device: str | None = None,
) -> Any:
    """Train ``member`` on ``suite`` (dqn, double-dqn, ps-dqn, ppo, dagger; the trainer ppo-numpy) or
    ``dataset`` (bc, cql), then (unless ``eval_suite`` is None) evaluate it; returns the trainer's
    ``Trained``, its card with the results. Files go into ``out`` (the module docstring). ``device``
    (the torch device, from ``--device`` / ``--backend``): ppo-numpy trains there (zoo/train/devppo.py)
    and the final evaluation runs its core there; None is the CPU's numpy path."""
    module = trainer(member)
    common: dict[str, Any] = {
        "member": member,
        "steps": steps,
        "seed": seed,
        "out": out,
        "resume": resume,
        "hyperparams": hyperparams,
        "overrides": overrides,
        "progress": progress,
    }
    if device is not None:
        if module.__name__.rsplit(".", 1)[-1] != "fastppo":
            raise UserError(f"--device {device}: only ppo-numpy trains on a device; {member} trains on the CPU")
        common["device"] = device
    if module.LEARNS_FROM == "dataset":
        if not dataset:
            raise UserError(f"{member} learns from a dataset: give --dataset NAME (see `overtakezoo dataset list`)")
        from overtakezoo.benchmark.datasets import store as datasets

        data = datasets.load(dataset)
        about = {
            "name": dataset,
            "content_sha256": datasets.content_sha256(data),
            "content_hash": f"{datasets.content_sha256.__module__}.{datasets.content_sha256.__qualname__}",
        }
        trained = module.train(data, about, **common)
    else:
        if dataset:
            raise UserError(f"--dataset is for the members trained offline; {member} trains on --suite")
        trained = module.train(load_training(suite), suite_name=suite, **common)
    if eval_suite:
        from overtakezoo.zoo.train.contract import write_outputs

        ev = load_suite(eval_suite)
        summary, results = evaluate(trained.decider(ev.config), ev, progress=progress, device=device)
        trained.card["results"][ev.name] = summary
        if out is not None:
            write_outputs(out, trained)
            results.save(Path(out) / f"{member}-{ev.name}.results.json")
    return trained


def evaluate(
    decider: Any, suite: Suite, progress: bool = False, limit: int | None = None, device: str | None = None
) -> tuple[dict[str, Any], Any]:
    """Run ``decider`` on ``suite`` with the benchmark runner (its core on the torch ``device`` when
    given: the same results): the card's summary and the Results."""
    on = {"backend": "torch", "device": device} if device else {}
    res = run_suite(suite, decider, progress=progress, limit=limit, **on)
    summary = outcome_summary(
        np.asarray(res.per["outcome"]), np.asarray(res.per["crash_lane"]), np.asarray(res.per["completion_time"], float)
    )
    summary.update(
        {
            "suite_version": suite.version,
            "suite_sha256": suite.hash,
            "measured_with": f"{run_suite.__module__}.{run_suite.__qualname__}",
        }
    )
    return summary, res


def outcome_summary(outcome: np.ndarray, crash_lane: np.ndarray, completion_time: np.ndarray) -> dict[str, Any]:
    """The results block of a model card, with 95 % Wilson intervals."""
    n = len(outcome)
    succ, crash, tout = (int((outcome == k).sum()) for k in (SUCCESS, CRASH, TIMEOUT))
    return {
        "count": n,
        "success": succ,
        "crash": crash,
        "timeout": tout,
        "offroad": n - succ - crash - tout,
        "success_rate": succ / n,
        "success_ci": list(wilson(succ, n)),
        "crash_rate": crash / n,
        "crash_ci": list(wilson(crash, n)),
        "timeout_rate": tout / n,
        # Lane 0 is the ego's lane (the lead, NPC1, in table1); lane 1 the opposite lane.
        "crash_lead_lane": int(((outcome == CRASH) & (crash_lane == 0)).sum()),
        "crash_opposite_lane": int(((outcome == CRASH) & (crash_lane == 1)).sum()),
        "mean_completion_time_s": float(np.nanmean(completion_time)) if succ else None,
    }


# ----------------------------------------------------------------------------- seed sweeps
def seed_dirs(out: str | Path, seeds: list[int]) -> list[Path]:
    """Where each seed of a sweep writes: ``<out>-s<seed>`` (runs/dqn -> runs/dqn-s0, runs/dqn-s1, ...)."""
    out = Path(out)
    return [out.with_name(f"{out.name}-s{seed}") for seed in seeds]


def _train_one(member: str, seed: int, out: str, kwargs: dict[str, Any]) -> dict[str, Any]:
    """One seed of a sweep (here or on a Ray worker): the files go into ``out``; the card comes back
    as JSON-able data (the driver needs nothing else)."""
    return train(member, seed=seed, out=out, **kwargs).card


def train_seeds(
    member: str,
    seeds: list[int],
    out: str | Path,
    engine: str = "auto",
    num_cpus: int | None = None,
    say: Any = print,
    **kwargs: Any,
) -> list[dict[str, Any]]:
    """Train ``member`` once per seed into :func:`seed_dirs`; returns the cards in seed order.

    ``engine``: ``ray`` runs the seeds as parallel Ray tasks on a local instance (``num_cpus`` of
    them at a time: Ray's default, every core), ``sequential`` one after the other here, ``auto``
    Ray when it is installed. Each seed's run is the same deterministic code with the same torch
    threads (the hyperparameter file's), so the files are the same bits either way."""
    if not seeds or len(set(seeds)) != len(seeds):
        raise UserError(f"--seeds: expected distinct seeds, got {seeds}")
    dirs = seed_dirs(out, seeds)
    if engine == "auto":
        engine = "ray" if importlib.util.find_spec("ray") is not None else "sequential"
    if engine == "sequential":
        cards = []
        for seed, where in zip(seeds, dirs, strict=True):
            say(f"seed {seed}: training into {where}")
            cards.append(_train_one(member, seed, str(where), kwargs))
        return cards
    if engine != "ray":
        raise UserError(f"engine {engine!r}: expected auto, ray or sequential")
    try:
        import ray
    except ImportError:
        raise UserError("--engine ray needs Ray: pip install -e '.[ray]'") from None
    started_here = not ray.is_initialized()
    if started_here:
        ray.init(num_cpus=num_cpus, include_dashboard=False, log_to_driver=False, configure_logging=False)
    try:
        task = ray.remote(num_cpus=1)(_train_one)
        quiet = {**kwargs, "progress": False}  # (bars from parallel workers would interleave)
        say(f"training {len(seeds)} seeds of {member} on Ray ({int(ray.cluster_resources().get('CPU', 0))} CPUs)")
        refs = [task.remote(member, seed, str(where.resolve()), quiet) for seed, where in zip(seeds, dirs, strict=True)]
        pending, cards = list(refs), {}
        while pending:
            done, pending = ray.wait(pending)
            for ref in done:
                seed = seeds[refs.index(ref)]
                cards[seed] = ray.get(ref)
                say(f"seed {seed}: done, files in {dirs[seeds.index(seed)]}")
    except ray.exceptions.RayTaskError as exc:
        cause = getattr(exc, "cause", None)
        if isinstance(cause, (UserError, ConfigError)):  # the one-line errors of a run here
            raise cause from None
        raise
    finally:
        if started_here:
            ray.shutdown()
    return [cards[seed] for seed in seeds]
