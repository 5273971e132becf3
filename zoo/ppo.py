"""PPO decider trained with rsl-rl-lib's ``OnPolicyRunner``; acts by the argmax of the policy logits.

Training (:func:`train`) runs rsl-rl's PPO on :class:`overtakezoo.envs.rsl_rl_env.OvertakeRslRlEnv`
with our categorical action distribution (:mod:`overtakezoo.zoo.categorical`) plugged in through
``actor.distribution_cfg["class_name"]``. The hyperparameters are data (``zoo/hyperparams/ppo.toml``).

The weights file holds the actor's ``state_dict`` and the rsl-rl model settings needed to rebuild
it (a plain dict, read with ``torch.load(weights_only=True)``); the model card ``ppo.json`` beside it
holds the provenance and the sha256 of the weights, checked before loading. Loading is local only.
"""

from __future__ import annotations

import contextlib
import copy
import csv
import dataclasses
import io
import json
import math
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict

from overtakezoo.benchmark.suites import load_training
from overtakezoo.envs import CRASH, SUCCESS, EnvConfig, OvertakeCore, observation_size
from overtakezoo.envs.io import atomic_path, atomic_write_bytes, check_writable_dir

from .base import Decider, register
from .common import WeightsError, evaluate, read_card, read_hyperparams, read_verified, sha256_bytes  # noqa: F401
from .features import FEATURES_VERSION, speed_relative

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")  # rsl_rl imports GitPython, which wants a git binary

HERE = Path(__file__).resolve().parent
HYPERPARAMS = HERE / "hyperparams" / "ppo.toml"
PRETRAINED = HERE / "pretrained"
WEIGHTS_FORMAT = "overtakezoo-ppo/1"
NUM_MODES = 3
# ----------------------------------------------------------------------------- data
def load_hyperparams(path: str | Path | None = None) -> dict[str, Any]:
    return read_hyperparams(path or HYPERPARAMS, {"train", "env", "runner", "algorithm", "actor", "critic"})


def train_cfg(hp: dict[str, Any]) -> dict[str, Any]:
    """rsl-rl's ``train_cfg`` from the hyperparameter sections (deep-copied: rsl-rl edits it)."""
    cfg = copy.deepcopy(hp["runner"])
    for key in ("algorithm", "actor", "critic"):
        cfg[key] = copy.deepcopy(hp[key])
    return cfg


# ----------------------------------------------------------------------------- policy
def build_actor(obs_dim: int, actor_cfg: dict[str, Any]) -> torch.nn.Module:
    """rsl-rl's ``MLPModel`` as the runner builds it (one observation group, one action column)."""
    from rsl_rl.utils import resolve_class

    cls, kwargs = resolve_class(actor_cfg)
    obs = TensorDict({"policy": torch.zeros(1, obs_dim)}, batch_size=[1])
    return cls(obs, {"actor": ["policy"]}, "actor", 1, **kwargs)


def weights_blob(actor: torch.nn.Module, obs_dim: int, actor_cfg: dict[str, Any]) -> bytes:
    buf = io.BytesIO()
    torch.save({"format": WEIGHTS_FORMAT, "obs_dim": obs_dim, "actor_cfg": actor_cfg,
                "state_dict": {k: v.detach().cpu() for k, v in actor.state_dict().items()}}, buf)
    return buf.getvalue()


def load_weights(weights: str | Path, card: dict[str, Any]) -> tuple[torch.nn.Module, int]:
    """The actor stored in ``weights`` after checking its sha256 against ``card``."""
    weights = Path(weights)
    data = read_verified(weights, card, "ppo")
    try:
        blob = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
        if blob.get("format") != WEIGHTS_FORMAT:
            raise ValueError(f"format {blob.get('format')!r}, expected {WEIGHTS_FORMAT!r}")
        actor = build_actor(int(blob["obs_dim"]), blob["actor_cfg"])
        actor.load_state_dict(blob["state_dict"])
    except Exception as exc:  # a hash-matching but unusable file: one line, not a traceback
        raise WeightsError(f"ppo: weights {weights.name}: cannot load ({type(exc).__name__}: {exc})") from None
    return actor.eval(), int(blob["obs_dim"])


class PPODecider(Decider):
    """PPO (rsl-rl) policy: the argmax of its logits over follow / overtake / abort."""

    name = "ppo"
    privileged = False

    def __init__(self, actor: torch.nn.Module, obs_dim: int, config: EnvConfig | None = None,
                 card: dict[str, Any] | None = None, action_repeat: int | None = None) -> None:
        super().__init__(config)
        if obs_dim != observation_size(self.config):
            raise WeightsError(f"ppo: policy expects {obs_dim} observation features, the configuration gives "
                               f"{observation_size(self.config)} (different planner/observation settings)")
        self.actor = actor.eval()
        self.model_card = card or {}
        self.version = str(self.model_card.get("version", "1"))
        self.weights_sha256 = self.model_card.get("weights_sha256")
        # Core steps each decision is held, exactly as in training (the runner applies the hold).
        self.action_repeat = int(action_repeat or self.model_card.get("action_repeat", 1))
        self.features = self.model_card.get("features")
        if self.features not in (None, FEATURES_VERSION):
            raise WeightsError(f"ppo: unknown input features {self.features!r} (this version has {FEATURES_VERSION!r})")

    def logits(self, obs: np.ndarray) -> np.ndarray:
        x = np.asarray(obs)
        if self.features:
            x = speed_relative(x, self.config)
        with torch.inference_mode():
            x = self.actor.obs_normalizer(torch.as_tensor(x, dtype=torch.float32))
            return self.actor.mlp(x).numpy()

    def act_batch(self, obs: np.ndarray) -> np.ndarray:
        """Argmax of the policy logits (stateless: the hold is the runner's)."""
        return self.logits(obs).argmax(axis=1).astype(np.int64)

    def card(self) -> str:
        c = self.model_card
        if not c:
            return "ppo: an untrained rsl-rl PPO policy."
        a = c.get("architecture", {})
        lines = [f"ppo (PPO, rsl-rl-lib {c.get('library_version', '?')}): MLP {a.get('hidden_dims')} "
                 f"{a.get('activation')} actor over the {a.get('obs_dim')}-feature observation, categorical "
                 f"over the 3 modes (argmax at test time), decision held {self.action_repeat} steps.",
                 f"  trained on {c['train_suite']['name']}, "
                 f"{c.get('steps')} decisions, seed {c.get('seed')}, {c.get('wall_time_s', 0):.0f} s wall "
                 f"({c.get('hyperparameters', {}).get('file')})."]
        res = c.get("results", {}).get("table1")
        if res:
            lines.append(f"  table1: success {100 * res['success_rate']:.2f} % [{100 * res['success_ci'][0]:.2f}, "
                         f"{100 * res['success_ci'][1]:.2f}], crash {100 * res['crash_rate']:.2f} % "
                         f"[{100 * res['crash_ci'][0]:.2f}, {100 * res['crash_ci'][1]:.2f}] (n={res['count']}).")
        lines.append(f"  weights sha256 {str(self.weights_sha256)[:16]}...")
        return "\n".join(lines)


def load_pretrained(config: EnvConfig | None = None, directory: str | Path | None = None) -> PPODecider:
    """``ppo.pt`` + ``ppo.json`` from ``zoo/pretrained`` (or ``directory``), sha256 checked."""
    directory = Path(directory) if directory else PRETRAINED
    card = read_card(directory / "ppo.json", "ppo")
    actor, obs_dim = load_weights(directory / "ppo.pt", card)
    return PPODecider(actor, obs_dim, config, card)


register("ppo", lambda config=None, **kw: load_pretrained(config, **kw))


# ----------------------------------------------------------------------------- evaluation
def rollout(decider: Decider, config: EnvConfig, scenarios: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every scenario run to its end under ``decider`` (one batch, each decision held as the runner
    holds it): outcome, crash lane, completion time."""
    from overtakezoo.envs.hold import hold, hold_steps

    core = OvertakeCore(config)
    obs = core.reset(scenarios)
    decider.reset()
    steps = hold_steps(config.decision_interval, decider.action_repeat)
    while not core.done.all():
        obs = hold(core, decider.act(obs), steps).obs
    return core.outcome, core.crash_lane, core.stats["completion_time"]


def greedy_score(decider: Decider, sets: list[tuple[EnvConfig, Any]]) -> float:
    """Success rate minus crash rate of ``decider`` over ``(config, scenarios)`` sets, each set
    weighted equally (model selection over a mixture of suites)."""
    scores = []
    for config, scenarios in sets:
        decider.config = config
        outcome, _, _ = rollout(decider, config, scenarios)
        scores.append(np.mean(outcome == SUCCESS) - np.mean(outcome == CRASH))
    return float(np.mean(scores))


# ----------------------------------------------------------------------------- training
def make_runner(env: Any, hp: dict[str, Any]) -> Any:
    from rsl_rl.runners import OnPolicyRunner

    with contextlib.redirect_stdout(io.StringIO()):  # rsl-rl prints the models and observation sets
        return OnPolicyRunner(env, train_cfg(hp), log_dir=None, device="cpu")


def _library_version() -> str:
    from importlib.metadata import version

    return version("rsl-rl-lib")


def train(suite: str = "table1-train", steps: int | None = None, seed: int = 0, out: str | Path | None = None,
          resume: str | Path | None = None, progress: bool = True, hyperparams: str | Path | None = None,
          eval_suite: str | None = "table1") -> Path:
    """Train PPO on ``suite`` (one suite, ``a+b``, or a mixture such as ``core-train``) for ``steps`` transitions (decisions); write ``out/ppo.pt`` + ``out/ppo.json`` (the
    model card, with ``eval_suite`` results), ``out/train_log.csv`` and ``out/checkpoints/``.
    ``resume`` continues from a checkpoint. Returns the path of the weights file."""
    from overtakezoo.envs.mixture import MixedCore, split_rows
    from overtakezoo.envs.rsl_rl_env import OvertakeRslRlEnv, pool_source

    hp = load_hyperparams(hyperparams)
    steps = int(steps if steps is not None else hp["train"]["steps"])
    out = Path(out) if out is not None else Path("runs") / f"ppo-seed{seed}"
    check_writable_dir(out / "checkpoints")  # fail before training, not after it
    torch.set_num_threads(int(hp["train"].get("threads", 1)))
    torch.manual_seed(seed)
    suites = load_training(suite)
    config = suites[0].config  # the observation layout, shared by every training suite
    pools = [s.scenarios() for s in suites]
    meta = {"name": suite, "suites": {s.name: s.hash for s in suites}}
    num_envs = int(hp["env"]["num_envs"])
    repeat = int(hp["env"].get("action_repeat", 1))
    core = MixedCore([s.config for s in suites], [pool_source(p) for p in pools], split_rows(num_envs, len(pools)),
                     seed=seed)
    env = OvertakeRslRlEnv(num_envs, config, seed=seed, core=core, transform=lambda o: speed_relative(o, config),
                           bootstrap_timeouts=bool(hp["env"].get("bootstrap_timeouts", True)), action_repeat=repeat)
    # Model selection: the greedy (argmax) policy on the first scenarios of each training suite.
    select_every = int(hp["train"].get("select_every", 0))
    per_suite = max(1, int(hp["train"].get("select_scenarios", 500)) // len(suites))
    select_sets = [(s.config, p.take(np.arange(min(per_suite, p.num)))) for s, p in zip(suites, pools)]
    selected = sum(sc.num for _, sc in select_sets)
    best: dict[str, Any] = {"score": -np.inf, "iteration": None, "state": None}
    runner = make_runner(env, hp)
    per_iter = num_envs * int(hp["runner"]["num_steps_per_env"])
    iterations = max(1, math.ceil(steps / per_iter))
    start_it, wall_before = 0, 0.0
    if resume is not None:
        infos = runner.load(str(resume), map_location="cpu") or {}
        start_it, wall_before = int(infos.get("iterations", 0)), float(infos.get("wall_time_s", 0.0))
        best = infos.get("best", best)

    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=iterations, initial=start_it, desc="ppo", unit="it")
    log_path = out / "train_log.csv"
    new_log = resume is None or not log_path.exists()
    t0 = time.perf_counter()
    with open(log_path, "w" if new_log else "a", newline="") as f:
        log = csv.writer(f)
        if new_log:
            log.writerow(["iteration", "env_steps", "wall_s", "episodes", "success_rate", "crash_rate",
                          "crash_ego_lane_rate", "crash_opposite_lane_rate", "timeout_rate", "learning_rate"])
        for it in range(start_it, iterations):
            before = dict(env.episode_counts)
            runner.learn(1)
            runner.current_learning_iteration = it + 1  # learn(1) does not advance it past the last iteration
            wall = wall_before + time.perf_counter() - t0
            done = {k: v - before.get(k, 0) for k, v in env.episode_counts.items()}
            eps = max(done.get("episodes", 0), 1)
            rates = {k: done.get(k, 0) / eps for k in ("success", "crash", "crash_ego_lane",
                                                          "crash_opposite_lane", "timeout")}
            log.writerow([it + 1, (it + 1) * per_iter, f"{wall:.1f}", done.get("episodes", 0)]
                         + [f"{rates[k]:.4f}" for k in rates] + [f"{runner.alg.learning_rate:.2e}"])
            f.flush()
            if bar is not None:
                bar.set_postfix(success=f"{rates['success']:.2f}", crash=f"{rates['crash']:.2f}")
                bar.update(1)
            if select_every and ((it + 1) % select_every == 0 or it + 1 == iterations):
                policy = runner.alg.get_policy()
                score = greedy_score(PPODecider(policy, observation_size(config), config, action_repeat=repeat,
                                                card={"features": FEATURES_VERSION}), select_sets)
                runner.alg.train_mode()  # the decider switched the shared actor to eval mode
                if score > best["score"]:
                    best = {"score": score, "iteration": it + 1,
                            "state": {k: v.detach().clone() for k, v in policy.state_dict().items()}}
                if bar is not None:
                    bar.write(f"iteration {it + 1}: greedy success - crash on {selected} training "
                              f"scenarios {score:.3f} (best {best['score']:.3f} at {best['iteration']})")
            if (it + 1) % int(hp["train"]["checkpoint_every"]) == 0 or it + 1 == iterations:
                with atomic_path(out / "checkpoints" / f"ppo_{it + 1:05d}.pt") as tmp:  # complete or absent
                    runner.save(str(tmp), infos={"iterations": it + 1, "wall_time_s": wall, "seed": seed,
                                                 "suite": meta, "best": best})
    if bar is not None:
        bar.close()
    wall = wall_before + time.perf_counter() - t0

    actor = runner.get_inference_policy("cpu")
    if best["state"] is not None:
        actor.load_state_dict(best["state"])
    blob = weights_blob(actor, observation_size(config), hp["actor"])
    card = {
        "name": "ppo", "version": "1", "algorithm": "PPO (clipped surrogate, GAE, adaptive KL learning rate)",
        "library": "rsl-rl-lib OnPolicyRunner", "library_version": _library_version(),
        "torch_version": torch.__version__,
        "features": FEATURES_VERSION,
        "architecture": {"obs_dim": observation_size(config), "hidden_dims": hp["actor"]["hidden_dims"],
                         "activation": hp["actor"]["activation"], "num_modes": NUM_MODES,
                         "distribution": hp["actor"]["distribution_cfg"]["class_name"]},
        "hyperparameters": {"file": hp["file"], **{k: hp[k] for k in ("train", "env", "runner", "algorithm",
                                                                       "actor", "critic") if k in hp}},
        "action_repeat": repeat, "training_reward": dataclasses.asdict(env.cfg.reward),
        "train_suite": meta, "steps": iterations * per_iter, "steps_unit": "decisions (env steps)",
        "iterations": iterations, "seed": seed,
        "selection": {"rule": "greedy success rate minus crash rate on the first training scenarios",
                      "scenarios": selected, "every": select_every, "iteration": best["iteration"],
                      "score": None if best["state"] is None else round(best["score"], 4)},
        "wall_time_s": round(wall, 1), "weights_sha256": sha256_bytes(blob), "weights_bytes": len(blob),
        "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "results": {},
    }
    weights = out / "ppo.pt"
    atomic_write_bytes(weights, blob)
    if eval_suite:
        decider = PPODecider(*load_weights(weights, card), config=config, card=card)
        card["results"][eval_suite] = evaluate(decider, eval_suite, progress=progress)[0]
    atomic_write_bytes(out / "ppo.json", (json.dumps(card, indent=1, sort_keys=True) + "\n").encode())
    return weights
