"""Training loop for the DQN / Double DQN deciders: many scenarios stepped in parallel in one process.

A :class:`~overtakezoo.envs.mixture.MixedCore` holds ``num_envs`` auto-reset rows split evenly over
the training suites (one suite, or a mixture such as ``core-train``: every core suite's training
split); a finished row is refilled with a scenario drawn from its own suite. The network sees the
speed-relative features of :mod:`overtakezoo.zoo.features`, the same at evaluation.
Every row decides at once
and each decision is held for ``action_repeat`` core steps (``overtakezoo.envs.hold``, the same hold
the benchmark runner applies at evaluation). Each decision gives one transition (obs, mode, summed
reward, next obs, done), all rows in one vectorized insert into a numpy ring buffer; ``next obs``
of a row whose episode ended during the hold is its final observation (the refilled row follows
until the next decision, and those steps belong to no transition).

Learning: epsilon-greedy (linear decay over the first ``eps_fraction`` of the steps), Huber loss,
Adam, gradient-norm clipping, a target network copied every ``target_update`` gradient steps; the
Double DQN target lets the online net pick and the target net evaluate (:func:`~.dqn.td_targets`).
Hyperparameters come from ``zoo/hyperparams/<algo>.toml``; ``steps`` counts decision transitions
summed over all rows.

Training reward: the env's own (the suite's ``RewardConfig``, which every face and trainer uses;
the hyperparameter file cannot change it). A timeout ends the episode as a failure
(``timeout_terminal``): the observation has no clock, and the time limit is part of the task.
"""

from __future__ import annotations

import copy
import csv
import dataclasses
import io
import time
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from overtakezoo.benchmark.suites import load_suite, load_training
from overtakezoo.envs import CRASH, SUCCESS, observation_size
from overtakezoo.envs.hold import hold
from overtakezoo.envs.mixture import MixedCore, split_rows
from overtakezoo.envs.io import atomic_write_bytes, atomic_write_json, check_writable_dir

from .common import evaluate, read_card, read_hyperparams, reject_reward_keys, sha256_bytes
from .features import FEATURES_VERSION, speed_relative
from .dqn import MASK_VERSION, NUM_MODES, DQNDecider, QNetwork, action_mask, masked_argmax, td_targets

HYPERPARAMS = Path(__file__).resolve().parent / "hyperparams"
ALGORITHMS = ("dqn", "double-dqn")
# Used only while the benchmark suites module is not available: disjoint seeds, the paper's counts.


class TrainError(ValueError):
    """Bad training input (unknown algorithm, malformed hyperparameters, unusable checkpoint)."""


# ----------------------------------------------------------------------------- inputs
def load_hyperparams(algo: str, path: str | Path | None = None) -> dict[str, Any]:
    if algo not in ALGORITHMS:
        raise TrainError(f"unknown algorithm {algo!r} (expected one of {', '.join(ALGORITHMS)})")
    required = {"double", "steps", "num_envs", "action_repeat", "gamma", "lr", "batch_size", "buffer_size",
                "learning_starts", "train_every", "target_update", "eps_start", "eps_end", "eps_fraction",
                "huber_delta", "grad_clip", "hidden", "dueling", "action_mask", "threads"}
    try:
        return read_hyperparams(path or HYPERPARAMS / f"{algo}.toml", required)
    except ValueError as exc:
        raise TrainError(str(exc)) from None


# ----------------------------------------------------------------------------- replay
class ReplayBuffer:
    """Fixed-size ring of transitions as numpy arrays; inserts and samples are vectorized."""

    def __init__(self, capacity: int, obs_dim: int) -> None:
        self.capacity, self.size, self.ptr = int(capacity), 0, 0
        self.obs = np.zeros((capacity, obs_dim), np.float32)
        self.next_obs = np.zeros((capacity, obs_dim), np.float32)
        self.action = np.zeros(capacity, np.int64)
        self.reward = np.zeros(capacity, np.float32)
        self.done = np.zeros(capacity, np.float32)

    def add(self, obs: np.ndarray, action: np.ndarray, reward: np.ndarray, next_obs: np.ndarray,
            done: np.ndarray) -> None:
        n = len(action)
        idx = (self.ptr + np.arange(n)) % self.capacity
        self.obs[idx], self.action[idx], self.reward[idx] = obs, action, reward
        self.next_obs[idx], self.done[idx] = next_obs, done
        self.ptr = int((self.ptr + n) % self.capacity)
        self.size = int(min(self.size + n, self.capacity))

    def sample(self, batch: int, rng: np.random.Generator) -> dict[str, torch.Tensor]:
        idx = rng.integers(0, self.size, batch)
        return {"obs": torch.from_numpy(self.obs[idx]), "action": torch.from_numpy(self.action[idx]),
                "reward": torch.from_numpy(self.reward[idx]), "next_obs": torch.from_numpy(self.next_obs[idx]),
                "done": torch.from_numpy(self.done[idx])}

    def state(self) -> dict[str, Any]:
        n = self.size
        return {"size": n, "ptr": self.ptr, "obs": self.obs[:n].copy(), "next_obs": self.next_obs[:n].copy(),
                "action": self.action[:n].copy(), "reward": self.reward[:n].copy(), "done": self.done[:n].copy()}

    def load(self, state: dict[str, Any]) -> None:
        n = min(int(state["size"]), self.capacity)
        for key in ("obs", "next_obs", "action", "reward", "done"):
            getattr(self, key)[:n] = np.asarray(state[key])[:n]
        self.size, self.ptr = n, int(state["ptr"]) % self.capacity


# ----------------------------------------------------------------------------- training
class Trainer:
    """State of one training run; :meth:`run` advances it, :meth:`checkpoint` / :meth:`restore`
    save and reload everything needed to continue (episodes in flight restart on resume)."""

    def __init__(self, algo: str, hp: dict[str, Any], suites: list[Any], seed: int, name: str | None = None) -> None:
        self.algo, self.hp, self.suites, self.seed = algo, hp, list(suites), int(seed)
        self.train_name = name or "+".join(s.name for s in self.suites)
        torch.manual_seed(self.seed)
        torch.set_num_threads(int(hp["threads"]))
        self.rng = np.random.default_rng(self.seed)
        try:
            reject_reward_keys(hp, "hyperparameters")  # also those given as overrides
        except ValueError as exc:
            raise TrainError(str(exc)) from None
        self.config = self.suites[0].config  # the observation layout, shared by every training suite
        self.obs_dim = observation_size(self.config)
        self.net = QNetwork(self.obs_dim, hp["hidden"], hp["dueling"])
        self.target = copy.deepcopy(self.net)
        self.optim = torch.optim.Adam(self.net.parameters(), lr=hp["lr"])
        self.buffer = ReplayBuffer(hp["buffer_size"], self.obs_dim)
        self.transitions = self.core_steps = self.updates = self.episodes = 0
        self.wall = 0.0
        self.recent: deque[int] = deque(maxlen=int(hp.get("stats_window", 1000)))
        self.last_loss = float("nan")
        self._core_seed = self.seed + 1

    # --- environment
    def _start_core(self) -> None:
        pools = [s.scenarios() for s in self.suites]
        sources = [lambda n, rng, pool=pool: pool.take(rng.integers(0, pool.num, n)) for pool in pools]
        sizes = split_rows(int(self.hp["num_envs"]), len(pools))
        self.core = MixedCore([s.config for s in self.suites], sources, sizes, seed=self._core_seed)
        self.obs = self._features(self.core.observe())

    def _features(self, obs: np.ndarray) -> np.ndarray:
        return speed_relative(obs, self.config).astype(np.float32)

    def epsilon(self) -> float:
        hp = self.hp
        frac = min(1.0, self.transitions / max(1.0, hp["eps_fraction"] * hp["steps"]))
        return hp["eps_start"] + frac * (hp["eps_end"] - hp["eps_start"])

    def _choose(self, obs: np.ndarray) -> np.ndarray:
        t = torch.from_numpy(obs)
        mask = (action_mask(t, self.config) if self.hp["action_mask"]
                else torch.ones(len(obs), NUM_MODES, dtype=torch.bool))
        with torch.no_grad():
            greedy = masked_argmax(self.net(t), mask).numpy()
        # Random modes drawn uniformly among the allowed ones.
        u = self.rng.random((len(obs), NUM_MODES)) * mask.numpy()
        rand = np.argmax(u, axis=1)
        explore = self.rng.random(len(obs)) < self.epsilon()
        return np.where(explore, rand, greedy).astype(np.int64)

    def _env_step(self) -> int:
        """One decision of every row, held ``action_repeat`` core steps; returns the core steps taken."""
        hp = self.hp
        act = self._choose(self.obs)
        res = hold(self.core, act, int(hp["action_repeat"]))
        self.core_steps += res.steps
        reward = res.reward.astype(np.float32)
        finished = res.finished
        obs = self._features(res.obs)
        next_obs = obs if res.final_obs is None else np.where(finished[:, None], self._features(res.final_obs), obs)
        done = res.terminated | (res.truncated & bool(hp.get("timeout_terminal", True)))
        self.buffer.add(self.obs, act, reward, next_obs, done.astype(np.float32))
        self.transitions += len(act)
        if finished.any():
            out = res.final_info["outcome"][finished]
            self.recent.extend(out.tolist())
            self.episodes += int(finished.sum())
        self.obs = obs
        return res.steps

    # --- learning
    def _learn(self) -> None:
        hp = self.hp
        b = self.buffer.sample(hp["batch_size"], self.rng)
        next_mask = action_mask(b["next_obs"], self.config) if hp["action_mask"] else None
        y = td_targets(self.net, self.target, b["reward"], b["next_obs"], b["done"], hp["gamma"], hp["double"],
                       next_mask)
        q = self.net(b["obs"]).gather(1, b["action"][:, None])[:, 0]
        loss = nn.functional.huber_loss(q, y, delta=hp["huber_delta"])
        self.optim.zero_grad(set_to_none=True)
        loss.backward()
        nn.utils.clip_grad_norm_(self.net.parameters(), hp["grad_clip"])
        self.optim.step()
        self.updates += 1
        self.last_loss = float(loss.detach())
        if self.updates % hp["target_update"] == 0:
            self.target.load_state_dict(self.net.state_dict())

    def rates(self) -> tuple[float, float]:
        if not self.recent:
            return float("nan"), float("nan")
        a = np.asarray(self.recent)
        return float((a == SUCCESS).mean()), float((a == CRASH).mean())

    def run(self, steps: int, out: Path | None = None, progress: bool = True) -> None:
        hp = self.hp
        self._start_core()
        log_every, ckpt_every = int(hp.get("log_every", 20000)), int(hp.get("checkpoint_every", 200000))
        next_log = (self.transitions // log_every + 1) * log_every
        next_ckpt = (self.transitions // ckpt_every + 1) * ckpt_every
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=steps, initial=min(self.transitions, steps), unit="tr", desc=self.algo,
                       dynamic_ncols=True, mininterval=1.0)
        log = _CsvLog(out / "log.csv") if out else None
        t0 = time.perf_counter() - self.wall
        while self.transitions < steps:
            before, steps_before = self.transitions, self.core_steps
            self._env_step()
            # A gradient step every `train_every` core steps, as many as the hold spanned.
            due = self.core_steps // hp["train_every"] - steps_before // hp["train_every"]
            if self.buffer.size >= hp["learning_starts"]:
                for _ in range(due * int(hp.get("gradient_steps", 1))):
                    self._learn()
            self.wall = time.perf_counter() - t0
            if bar is not None and self.transitions > before:
                bar.update(min(self.transitions, steps) - min(before, steps))
            if self.transitions >= next_log:
                next_log += log_every
                s, c = self.rates()
                if bar is not None:
                    bar.set_postfix(success=f"{s:.2f}", crash=f"{c:.2f}", eps=f"{self.epsilon():.2f}", refresh=False)
                if log:
                    log.write({"steps": self.transitions, "episodes": self.episodes, "success_rate": round(s, 4),
                               "crash_rate": round(c, 4), "loss": round(self.last_loss, 5),
                               "epsilon": round(self.epsilon(), 4), "updates": self.updates,
                               "wall_time_s": round(self.wall, 2)})
            if out and self.transitions >= next_ckpt:
                next_ckpt += ckpt_every
                self.checkpoint(out / "checkpoint.pt")
        if bar is not None:
            bar.close()
        if out:
            self.checkpoint(out / "checkpoint.pt")

    # --- persistence
    def checkpoint(self, path: Path) -> None:
        state = {"algo": self.algo, "hp": self.hp, "seed": self.seed, "net": self.net.state_dict(),
                 "target": self.target.state_dict(), "optim": self.optim.state_dict(),
                 "counters": [self.transitions, self.core_steps, self.updates, self.episodes],
                 "wall": self.wall, "recent": list(self.recent), "rng": self.rng.bit_generator.state,
                 "torch_rng": torch.get_rng_state(), "core_seed": self._core_seed + 1,
                 "buffer": self.buffer.state()}
        buf = io.BytesIO()
        torch.save(state, buf)
        atomic_write_bytes(path, buf.getvalue())

    def restore(self, path: str | Path) -> None:
        try:
            state = torch.load(path, map_location="cpu", weights_only=False)
        except Exception as exc:  # truncated / foreign files fail in many ways; one line for all
            why = (str(exc).splitlines() or [type(exc).__name__])[0].split(". ")[0]
            raise TrainError(f"cannot read checkpoint {path}: {why}") from None
        if state.get("algo") != self.algo:
            raise TrainError(f"checkpoint {path} is for {state.get('algo')!r}, not {self.algo!r}")
        self.net.load_state_dict(state["net"])
        self.target.load_state_dict(state["target"])
        self.optim.load_state_dict(state["optim"])
        self.transitions, self.core_steps, self.updates, self.episodes = state["counters"]
        self.wall = state["wall"]
        self.recent.extend(state["recent"])
        self.rng.bit_generator.state = state["rng"]
        torch.set_rng_state(state["torch_rng"])
        self._core_seed = state["core_seed"]  # episodes in flight restart with fresh draws
        self.buffer.load(state["buffer"])

    def decider(self) -> DQNDecider:
        return DQNDecider(copy.deepcopy(self.net).eval(), name=self.algo, config=self.config,
                          action_repeat=self.hp["action_repeat"], use_mask=self.hp["action_mask"],
                          card={"features": FEATURES_VERSION})


class _CsvLog:
    FIELDS = ["steps", "episodes", "success_rate", "crash_rate", "loss", "epsilon", "updates", "wall_time_s"]

    def __init__(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        new = not path.exists()
        self.f = open(path, "a", newline="")
        self.w = csv.DictWriter(self.f, fieldnames=self.FIELDS)
        if new:
            self.w.writeheader()

    def write(self, row: dict[str, Any]) -> None:
        self.w.writerow(row)
        self.f.flush()


def model_card(trainer: Trainer, weights: bytes, results: dict[str, Any] | None,
               eval_suite: Any) -> dict[str, Any]:
    hp = trainer.hp
    suite_name = trainer.train_name
    return {
        "name": trainer.algo, "version": "1",
        "algorithm": "Double DQN (van Hasselt et al. 2016)" if hp["double"] else "DQN (Mnih et al. 2015)",
        "architecture": {"obs_dim": trainer.obs_dim, "hidden": list(hp["hidden"]), "dueling": bool(hp["dueling"]),
                         "num_actions": NUM_MODES},
        "action_repeat": int(hp["action_repeat"]), "action_mask": bool(hp["action_mask"]),
        "action_mask_version": MASK_VERSION,
        "hyperparameters": {k: v for k, v in hp.items()},
        "training_reward": dataclasses.asdict(trainer.config.reward),
        "features": FEATURES_VERSION,
        "train_suite": suite_name, "train_suites": {s.name: s.hash for s in trainer.suites},
        "steps": trainer.transitions, "core_steps": trainer.core_steps, "gradient_updates": trainer.updates,
        "episodes": trainer.episodes, "seed": trainer.seed, "wall_time_s": round(trainer.wall, 1),
        "results": {eval_suite.name: results} if results and eval_suite else {},
        "eval_suite": eval_suite.name if eval_suite else None,
        "eval_suite_hash": eval_suite.hash if eval_suite else None,
        "weights_file": f"{trainer.algo}.pt", "weights_sha256": sha256_bytes(weights),
        "torch": torch.__version__,
        "reproduce": (f"overtakezoo train {trainer.algo} --suite {suite_name} --steps {hp['steps']} "
                      f"--seed {trainer.seed}"),
    }


def train(algo: str = "dqn", suite: str = "table1-train", steps: int | None = None, seed: int | None = None,
          out: str | Path | None = None, resume: str | Path | None = None, hyperparams: str | Path | None = None,
          overrides: dict[str, Any] | None = None, eval_suite: str | None = "table1", progress: bool = True
          ) -> dict[str, Any]:
    """Train ``algo`` and (unless ``eval_suite`` is None) evaluate it; writes ``log.csv``,
    ``checkpoint.pt``, ``<algo>.pt`` and the model card ``<algo>.json`` into ``out``.
    Returns the model card (dict)."""
    out_dir = check_writable_dir(out) if out else None  # fail before training, not after it
    hp = load_hyperparams(algo, hyperparams)
    hp.update(overrides or {})
    if steps is not None:
        hp["steps"] = int(steps)
    seed = int(hp.get("seed", 0) if seed is None else seed)
    hp["seed"] = seed
    trainer = Trainer(algo, hp, load_training(suite), seed, name=suite)
    if resume:
        trainer.restore(resume)
    trainer.run(int(hp["steps"]), out_dir, progress)
    buf = io.BytesIO()
    torch.save(trainer.net.state_dict(), buf)
    weights = buf.getvalue()
    results, ev, full = None, None, None
    if eval_suite:
        ev = load_suite(eval_suite)
        dec = trainer.decider()
        dec.config, dec.weights_sha256 = ev.config, sha256_bytes(weights)
        results, full = evaluate(dec, ev)
    card = model_card(trainer, weights, results, ev)
    if out_dir:
        atomic_write_bytes(out_dir / f"{algo}.pt", weights)
        atomic_write_json(out_dir / f"{algo}.json", card)
        if eval_suite and full is not None:  # the runner's results file, ready for `overtakezoo submit`
            full.save(out_dir / f"{algo}-{eval_suite}.results.json")
    card["_net"] = trainer.net  # for callers in-process (tests); not serialized
    return card



def evaluate_pretrained(name: str, suite: str = "table1", directory: str | Path | None = None,
                        write: bool = False) -> dict[str, Any]:
    """Re-measure a published decider on ``suite`` (e.g. after a suite or code change); with
    ``write`` the model card's ``results[suite]`` is replaced (the weights, and so their sha256,
    stay as they are)."""
    from .dqn import PRETRAINED, load_pretrained

    directory = Path(directory) if directory else PRETRAINED
    data = load_suite(suite)
    dec = load_pretrained(name, data.config, directory)
    summary, _ = evaluate(dec, data)
    if write:
        card = read_card(directory / f"{name}.json", name)
        card.setdefault("results", {})[suite] = summary
        if suite == "table1":
            card["eval_suite"], card["eval_suite_hash"] = data.name, data.hash
        atomic_write_json(directory / f"{name}.json", card)
    return summary
