"""PPO training with rsl-rl-lib's ``OnPolicyRunner`` (the ``ppo`` member; acting is
:mod:`overtakezoo.zoo.members.learned`, numpy only, as for every learned member).

Training (:func:`train`) runs rsl-rl's PPO on :class:`overtakezoo.envs.faces.rsl_rl.OvertakeRslRlEnv`
with our categorical action distribution (:mod:`.categorical`) plugged in through
``actor.distribution_cfg["class_name"]``. The hyperparameters are data (``zoo/hyperparams/ppo.toml``),
typed by :class:`PPOHyperparams`: ``[train]`` and ``[env]`` are ours; ``[runner]``, ``[algorithm]``,
``[actor]``, ``[critic]`` go to rsl-rl as they are, their keys checked against what rsl-rl reads.
Each decision is held ``action_repeat`` core steps (10 in ``ppo.toml``). The training reward is the
env's own, as for every trainer (the suite's ``RewardConfig``, time cost included).

:func:`train` takes the training suites loaded and returns the :class:`~.contract.Trained` member.
Outputs (:mod:`.contract`): ``ppo.pt`` holds the actor's ``state_dict`` and the rsl-rl model
settings needed to rebuild it (a plain dict, read with ``torch.load(weights_only=True)``), converted
to ``ppo.npz`` (:func:`.export.convert`); the model card ``ppo.json`` names both with their sha256.
Beside them: ``train_log.csv`` and ``checkpoints/``. (A little over the project's ~300 lines: the
hyperparameter checks against rsl-rl and the training loop with its model selection are ppo's alone.)
"""

from __future__ import annotations

import contextlib
import copy
import csv
import inspect
import io
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from overtakezoo.envs import EnvConfig, observation_size
from overtakezoo.envs.config import unknown_key
from overtakezoo.envs.io import atomic_path, check_writable_dir
from overtakezoo.zoo.members.features import speed_relative
from overtakezoo.zoo.train.contract import (
    RUN_FILES,
    Trained,
    TrainError,
    finish,
    hyperparams_file,
    load_hyperparams,
    model_card,
    refuse_other_trainers,
    reproduce,
    suite_source,
)
from overtakezoo.zoo.train.export import PPO_FORMAT
from overtakezoo.zoo.train.typed import HyperparameterError, param

if TYPE_CHECKING:
    import torch
    from rsl_rl.models.mlp_model import MLPModel  # (rsl-rl has no type hints: Any to mypy)

# torch, tensordict and rsl-rl are imported where they are used: a hyperparameter file of the numpy
# PPO (ppo-numpy.toml, `overtakezoo train ppo-numpy`, :mod:`.fastppo`) is refused without importing them.
os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")  # rsl_rl imports GitPython, which wants a git binary

LEARNS_FROM = "suites"  # what train() takes: loaded training suites, or a loaded dataset
STEPS_UNIT = "decisions (env steps)"


# ----------------------------------------------------------------------------- hyperparameters
@dataclass(frozen=True)
class TrainSection:
    steps: int = param(lo=1)  # decisions (env steps: num_envs * num_steps_per_env per iteration)
    threads: int = param(1, 1, 1024)  # torch CPU threads
    checkpoint_every: int = param(lo=1)  # iterations between checkpoints
    select_every: int = param(0, 0)  # iterations between model-selection runs (0: none, keep the last)
    select_scenarios: int = param(500, 1)  # training scenarios the greedy policy is scored on
    # Added to the actor's initial OVERTAKE logit (its last layer's bias; rsl-rl's init leaves all three at 0):
    # the exploration start, as fastppo's [ppo] overtake_bias. 0: rsl-rl's near-uniform initial policy.
    overtake_bias: float = param(0.0, -10.0, 10.0)


@dataclass(frozen=True)
class EnvSection:
    num_envs: int = param(lo=1, hi=1_000_000)
    bootstrap_timeouts: bool = param(True)
    action_repeat: int = param(1, 1, 1000)


@dataclass(frozen=True)
class PPOHyperparams:
    train: TrainSection = param()
    env: EnvSection = param()
    runner: dict[str, Any] = param()
    algorithm: dict[str, Any] = param()
    actor: dict[str, Any] = param()
    critic: dict[str, Any] = param()

    @classmethod
    def check(cls, hp: PPOHyperparams, where: str) -> None:  # called by contract.load_hyperparams
        check_rsl_rl_keys(hp, where)


# [runner] keys rsl-rl-lib 5.5's OnPolicyRunner and its logger read (it ignores any other key).
RUNNER_KEYS = (
    "num_steps_per_env",
    "save_interval",
    "obs_groups",
    "check_for_nan",
    "logger",
    "wandb_project",
    "neptune_project",
    "run_name",
    "torch_compile_mode",
)
# Constructor arguments rsl-rl fills itself (not settings of a hyperparameter file).
_SUPPLIED = {
    "self",
    "actor",
    "critic",
    "storage",
    "device",
    "multi_gpu_cfg",
    "obs",
    "obs_groups",
    "obs_set",
    "output_dim",
}


def check_rsl_rl_keys(hp: PPOHyperparams, where: str) -> None:
    """Refuse keys rsl-rl would ignore ([runner]) or fail on later ([algorithm], [actor], [critic]:
    the keyword arguments of the classes they name), naming the key."""
    for key in hp.runner:
        if key not in RUNNER_KEYS:
            raise HyperparameterError(f"{where}: runner.{key}: {unknown_key(key, RUNNER_KEYS)}")
    from rsl_rl.utils import resolve_callable

    for section in ("algorithm", "actor", "critic"):
        cfg = getattr(hp, section)
        if "class_name" not in cfg:
            raise HyperparameterError(f"{where}: {section}.class_name: missing (required)")
        try:
            cls = resolve_callable(cfg["class_name"])
        except Exception as exc:
            raise HyperparameterError(
                f"{where}: {section}.class_name: {cfg['class_name']!r} cannot be resolved ({type(exc).__name__}: {exc})"
            ) from None
        params = inspect.signature(cls).parameters
        if any(p.kind is p.VAR_KEYWORD for p in params.values()):
            continue  # the class takes any keyword
        known = ["class_name", *(n for n in params if n not in _SUPPLIED)]
        for key in cfg:
            if key not in known:
                raise HyperparameterError(f"{where}: {section}.{key}: {unknown_key(key, known)}")


def train_cfg(hp: PPOHyperparams) -> dict[str, Any]:
    """rsl-rl's ``train_cfg`` from the hyperparameter sections (deep-copied: rsl-rl edits it)."""
    cfg = copy.deepcopy(hp.runner)
    for key in ("algorithm", "actor", "critic"):
        cfg[key] = copy.deepcopy(getattr(hp, key))
    return cfg


# ----------------------------------------------------------------------------- policy
def build_actor(obs_dim: int, actor_cfg: dict[str, Any]) -> torch.nn.Module:
    """rsl-rl's ``MLPModel`` as the runner builds it (one observation group, one action column)."""
    import torch
    from rsl_rl.utils import resolve_class
    from tensordict import TensorDict

    cls, kwargs = resolve_class(actor_cfg)
    obs = TensorDict({"policy": torch.zeros(1, obs_dim)}, batch_size=[1])
    return cls(obs, {"actor": ["policy"]}, "actor", 1, **kwargs)


def weights_blob(actor: torch.nn.Module, obs_dim: int, actor_cfg: dict[str, Any]) -> bytes:
    import torch

    buf = io.BytesIO()
    torch.save(
        {
            "format": PPO_FORMAT,
            "obs_dim": obs_dim,
            "actor_cfg": actor_cfg,
            "state_dict": {k: v.detach().cpu() for k, v in actor.state_dict().items()},
        },
        buf,
    )
    return buf.getvalue()


def greedy_actor(actor: MLPModel) -> Any:
    """The actor being trained, acting greedily (float32, through torch) for model selection:
    ``act(obs, config)`` as :func:`.selection.greedy_score` calls it."""
    import torch

    actor.eval()

    def act(obs: np.ndarray, config: EnvConfig) -> np.ndarray:
        with torch.inference_mode():
            x = actor.obs_normalizer(torch.as_tensor(speed_relative(np.asarray(obs), config), dtype=torch.float32))
            return actor.mlp(x).numpy().argmax(axis=1).astype(np.int64)

    return act


# ----------------------------------------------------------------------------- training
def make_runner(env: Any, hp: PPOHyperparams) -> Any:
    from rsl_rl.runners import OnPolicyRunner

    with contextlib.redirect_stdout(io.StringIO()):  # rsl-rl prints the models and observation sets
        return OnPolicyRunner(env, train_cfg(hp), log_dir=None, device="cpu")


def start_biased(actor: MLPModel, overtake_bias: float) -> None:
    """Add ``overtake_bias`` to the untrained ``actor``'s OVERTAKE logit (the bias of its last layer,
    which :class:`.categorical.CategoricalDistribution` initializes to zero): the initial policy overtakes
    with probability e^b / (e^b + 2) per decision (b = 2: ~0.79) instead of 1/3."""
    import torch

    from overtakezoo.envs.config import OVERTAKE

    if overtake_bias:
        with torch.no_grad():
            actor.mlp[-1].bias[OVERTAKE] += overtake_bias


def _library_version() -> str:
    from importlib.metadata import version

    return version("rsl-rl-lib")


def load_checkpoint(runner: Any, path: str | Path) -> dict[str, Any]:
    """Restore ``runner`` from a checkpoint ``runner.save`` wrote and return its ``infos``. Read with
    ``weights_only=True`` (rsl-rl's own ``load`` unpickles anything): resuming never runs code."""
    import torch

    try:
        loaded = torch.load(str(path), map_location="cpu", weights_only=True)
        if not isinstance(loaded, dict):
            raise TypeError("not a checkpoint dictionary")
        if runner.alg.load(loaded, None, True):
            runner.current_learning_iteration = loaded["iter"]
    except Exception as exc:  # a foreign, truncated or pickled-object file: one line
        why = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:300]
        raise TrainError(f"cannot read checkpoint {path}: {why}") from None
    return loaded.get("infos") or {}


def train(
    suites: list[Any],
    *,
    member: str = "ppo",
    suite_name: str | None = None,
    steps: int | None = None,
    seed: int | None = None,
    out: str | Path | None = None,
    resume: str | Path | None = None,
    hyperparams: str | Path | None = None,
    overrides: dict[str, Any] | None = None,
    progress: bool = True,
) -> Trained:
    """Train PPO on the loaded training ``suites`` (one suite or a mixture such as ``core-train``;
    ``suite_name``: the spec they came from, for the card) for ``steps`` transitions (decisions),
    seed ``seed`` (default 0); write into ``out`` (default ``runs/ppo-seed<seed>``) ``train_log.csv``,
    ``checkpoints/`` and the outputs ``ppo.pt``, ``ppo.npz``, ``ppo.json``. ``resume`` continues
    from a checkpoint; ``overrides`` ({"train": {"steps": ...}}) go through the same checks as the
    file (default ``zoo/hyperparams/ppo.toml``)."""
    if member != "ppo":
        raise TrainError(f"train/ppo.py trains ppo, not {member!r}")
    # One PPO trainer per name: the numpy PPO's files ([ppo]) are ppo-numpy's, never a switch of trainer.
    refuse_other_trainers(hyperparams or hyperparams_file("ppo"), "ppo", {"ppo-numpy": ("ppo",)})
    try:
        import rsl_rl  # noqa: F401
        import torch
    except ModuleNotFoundError as exc:  # the same line as for a trainer module that imports it at the top
        raise TrainError(f"training ppo needs {exc.name} (pip install -e '.[train]')") from None

    from overtakezoo.envs.faces.rsl_rl import OvertakeRslRlEnv, pool_source
    from overtakezoo.envs.mixture import MixedCore, split_rows
    from overtakezoo.zoo.train.selection import greedy_score, selection_sets

    hp, hp_file = load_hyperparams(PPOHyperparams, hyperparams or hyperparams_file("ppo"), overrides)
    steps = int(steps if steps is not None else hp.train.steps)
    seed = 0 if seed is None else int(seed)
    out = Path(out) if out is not None else Path("runs") / f"ppo-seed{seed}"
    check_writable_dir(out / "checkpoints")  # fail before training, not after it
    torch.set_num_threads(hp.train.threads)
    torch.manual_seed(seed)
    source = suite_source(suites, suite_name)
    meta = source["train_suite"]  # recorded in every checkpoint too
    config = suites[0].config  # the observation layout, shared by every training suite
    pools = [s.scenarios() for s in suites]
    num_envs = hp.env.num_envs
    repeat = hp.env.action_repeat
    core = MixedCore(
        [s.config for s in suites], [pool_source(p) for p in pools], split_rows(num_envs, len(pools)), seed=seed
    )
    env = OvertakeRslRlEnv(
        num_envs,
        config,
        seed=seed,
        core=core,
        transform=lambda o: speed_relative(o, config),
        bootstrap_timeouts=hp.env.bootstrap_timeouts,
        action_repeat=repeat,
    )
    # Model selection: the greedy (argmax) policy on the first scenarios of each training suite.
    select_every = hp.train.select_every
    select_sets = selection_sets(suites, pools, hp.train.select_scenarios)
    selected = sum(sc.num for _, sc in select_sets)
    best: dict[str, Any] = {"score": -np.inf, "iteration": None, "state": None}
    runner = make_runner(env, hp)
    start_biased(runner.alg.get_policy(), hp.train.overtake_bias)  # (a resumed checkpoint overwrites it)
    per_iter = num_envs * int(hp.runner["num_steps_per_env"])
    iterations = max(1, math.ceil(steps / per_iter))
    start_it, wall_before = 0, 0.0
    if resume is not None:
        infos = load_checkpoint(runner, resume)
        start_it, wall_before = int(infos.get("iterations", 0)), float(infos.get("wall_time_s", 0.0))
        best = infos.get("best", best)

    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=iterations, initial=start_it, desc="ppo", unit="it")
    log_path = out / RUN_FILES["ppo"][0]
    new_log = resume is None or not log_path.exists()
    t0 = time.perf_counter()
    with open(log_path, "w" if new_log else "a", newline="") as f:
        log = csv.writer(f)
        if new_log:
            log.writerow(
                [
                    "iteration",
                    "env_steps",
                    "wall_s",
                    "episodes",
                    "success_rate",
                    "crash_rate",
                    "crash_ego_lane_rate",
                    "crash_opposite_lane_rate",
                    "timeout_rate",
                    "learning_rate",
                ]
            )
        for it in range(start_it, iterations):
            before = dict(env.episode_counts)
            runner.learn(1)
            runner.current_learning_iteration = it + 1  # learn(1) does not advance it past the last iteration
            wall = wall_before + time.perf_counter() - t0
            done = {k: v - before.get(k, 0) for k, v in env.episode_counts.items()}
            eps = max(done.get("episodes", 0), 1)
            rates = {
                k: done.get(k, 0) / eps
                for k in ("success", "crash", "crash_ego_lane", "crash_opposite_lane", "timeout")
            }
            log.writerow(
                [it + 1, (it + 1) * per_iter, f"{wall:.1f}", done.get("episodes", 0)]
                + [f"{rates[k]:.4f}" for k in rates]
                + [f"{runner.alg.learning_rate:.2e}"]
            )
            f.flush()
            if bar is not None:
                bar.set_postfix(success=f"{rates['success']:.2f}", crash=f"{rates['crash']:.2f}")
                bar.update(1)
            if select_every and ((it + 1) % select_every == 0 or it + 1 == iterations):
                policy = runner.alg.get_policy()
                score = greedy_score(greedy_actor(policy), select_sets, repeat)
                runner.alg.train_mode()  # greedy_actor switched the shared actor to eval mode
                if score > best["score"]:
                    best = {
                        "score": float(score),
                        "iteration": it + 1,
                        "state": {k: v.detach().clone() for k, v in policy.state_dict().items()},
                    }
                if bar is not None:
                    bar.write(
                        f"iteration {it + 1}: greedy success - crash on {selected} training "
                        f"scenarios {score:.3f} (best {best['score']:.3f} at {best['iteration']})"
                    )
            if (it + 1) % hp.train.checkpoint_every == 0 or it + 1 == iterations:
                ckpt = out / RUN_FILES["ppo"][1].replace("<iteration>", f"{it + 1:05d}")
                with atomic_path(ckpt) as tmp:  # complete or absent
                    runner.save(
                        str(tmp),
                        infos={"iterations": it + 1, "wall_time_s": wall, "seed": seed, "suite": meta, "best": best},
                    )
    if bar is not None:
        bar.close()
    wall = wall_before + time.perf_counter() - t0

    actor = runner.get_inference_policy("cpu")
    if best["state"] is not None:
        actor.load_state_dict(best["state"])
    blob = weights_blob(actor, observation_size(config), hp.actor)
    selection = {
        "rule": "greedy success rate minus crash rate on the first training scenarios",
        "scenarios": selected,
        "every": select_every,
        "iteration": best["iteration"],
        "score": None if best["state"] is None else round(best["score"], 4),
    }
    card = model_card(
        "ppo",
        algorithm=ALGORITHM,
        architecture={"kind": "policy"},
        hp=hp,
        hp_file=hp_file,
        action_repeat=repeat,
        action_mask=False,
        source=source,
        steps=iterations * per_iter,
        steps_unit=STEPS_UNIT,
        seed=seed,
        wall_time_s=wall,
        training={"iterations": iterations, "selection": selection},
        reproduce=reproduce("ppo", source, steps, seed),
        versions={"rsl-rl-lib": _library_version()},
    )
    return finish(card, weights=blob, module=actor, out=out)


ALGORITHM = (
    "PPO (Schulman et al. 2017: clipped surrogate, GAE, adaptive KL learning rate) through rsl-rl-lib's OnPolicyRunner"
)
