"""DQN and Double DQN training (dqn, double-dqn, ps-dqn), top to bottom: hyperparameters, acting,
the loop, checkpoints, the card (in the spirit of CleanRL's single-file ``dqn.py``; the network,
the replay buffer and the TD target are :mod:`.qlearning`, shared with cql and bc). At ~380 lines
it is over the project's ~300: the loop and its checkpoints are one state machine (:class:`Trainer`)
that reads best in one file.

Many scenarios are stepped in parallel in one process: a :class:`~overtakezoo.envs.mixture.MixedCore`
holds ``num_envs`` auto-reset rows split evenly over the training suites (one suite, or a mixture
such as ``core-train``: every core suite's training split); a finished row is refilled with a
scenario drawn from its own suite. The network sees the speed-relative features of
:mod:`overtakezoo.zoo.members.features`, the same at evaluation. Every row decides at once and each decision
is held for ``action_repeat`` core steps (``overtakezoo.envs.hold``, the same hold the benchmark
runner applies at evaluation). Each decision gives one transition (obs, mode, summed reward, next
obs, done), all rows in one vectorized insert into a numpy ring buffer; ``next obs`` of a row whose
episode ended during the hold is its final observation (the refilled row follows until the next
decision, and those steps belong to no transition). With ``n_step`` > 1 (the shipped files: 3) the
transitions are n-step ones, built per row by :class:`~.qlearning.NStepReturns` and stored when
complete; the TD target discounts each by gamma^k.

Several automated vehicles per road (the multi-AV suites ``duel``, ``platoon``, ``mixed-traffic``):
every AV row is a learner and all share the one Q-network -- parameter sharing (Gupta et al. 2017,
"Cooperative Multi-agent Control Using Deep Reinforcement Learning"), so the policy meets copies of
itself on the road (self-play). Each AV row's transitions go into the one buffer, except those of
rows *waiting* at the decision: an AV that is done stands frozen until its road ends, and its
decisions then belong to no episode (``HeldStep.waiting``). ``multi_av_share`` sets the share of
the rows given to multi-AV suites in a mixture (``ps-dqn.toml``: ``core-train+multi-train``).

Learning: epsilon-greedy over the modes the action mask allows (linear decay over the first
``eps_fraction`` of the steps), Huber loss, Adam, gradient-norm clipping, a target network copied
every ``target_update`` gradient steps; the Double DQN target lets the online net pick and the target
net evaluate. The shipped members use a dueling head (``dueling``: value + mean-centred advantages,
Wang et al. 2016). Hyperparameters come from ``zoo/hyperparams/<algo>.toml``, typed by
:class:`DQNHyperparams`; ``steps`` counts decision transitions summed over all rows.

Training reward: the env's own (the suite's ``RewardConfig``, which every face and trainer uses;
the hyperparameter file cannot change it). A timeout ends the episode as a failure
(``timeout_terminal``): the observation has no clock, and the time limit is part of the task.

:func:`train` takes the training suites loaded (``overtakezoo.benchmark.suite_groups.load_training``) and
returns the :class:`~.contract.Trained` member; into ``out`` it writes ``log.csv``,
``checkpoint.pt`` and the contract's outputs: ``<algo>.pt`` (the Q-network's ``state_dict``), its
numpy export ``<algo>.npz`` and the model card ``<algo>.json`` (:mod:`.contract`). Acting needs
only the ``.npz`` (:mod:`overtakezoo.zoo.members.learned`).
"""

from __future__ import annotations

import copy
import csv
import dataclasses
import io
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from overtakezoo.envs import CRASH, SUCCESS, observation_size
from overtakezoo.envs.hold import hold
from overtakezoo.envs.io import atomic_write_bytes, check_writable_dir
from overtakezoo.envs.mixture import MixedCore, split_rows
from overtakezoo.envs.model.observation import OPTIONAL_PARTS
from overtakezoo.zoo.base import member as registry_member
from overtakezoo.zoo.base import names
from overtakezoo.zoo.members.features import speed_relative
from overtakezoo.zoo.members.learned import NUM_MODES, action_mask
from overtakezoo.zoo.members.learned import masked_argmax as numpy_masked_argmax
from overtakezoo.zoo.train.contract import (
    RUN_FILES,
    Trained,
    TrainError,
    finish,
    hyperparams_file,
    load_hyperparams,
    model_card,
    reproduce,
    suite_source,
)
from overtakezoo.zoo.train.qlearning import NStepReturns, QNetwork, ReplayBuffer, masked_argmax, td_targets
from overtakezoo.zoo.train.selection import greedy_score, selection_sets
from overtakezoo.zoo.train.typed import as_dict, param

LEARNS_FROM = "suites"  # what train() takes: loaded training suites, or a loaded dataset
STEPS_UNIT = "decision transitions, summed over all rows"


def members() -> list[str]:
    """The members this module trains (the registry's learned members whose trainer is ``dqn``)."""
    return [n for n in names("learned") if registry_member(n).trainer == "dqn"]


# ----------------------------------------------------------------------------- hyperparameters
@dataclass(frozen=True)
class DQNHyperparams:
    """``zoo/hyperparams/dqn.toml`` and ``double-dqn.toml`` (the comments there say why each value)."""

    double: bool = param()  # Double DQN target (van Hasselt et al. 2016)
    seed: int = param(0, 0, 2**32 - 1)
    steps: int = param(lo=1)  # decision transitions, summed over all rows
    num_envs: int = param(lo=1, hi=1_000_000)  # rows stepped at once
    action_repeat: int = param(lo=1, hi=1000)  # core steps each decision is held
    action_mask: bool = param()  # the mode-transition mask (zoo/members/learned.py)
    gamma: float = param(lo=0.0, hi=1.0)  # discount per decision
    n_step: int = param(1, 1, 100)  # decisions per TD target (1: one-step DQN; qlearning.NStepReturns)
    lr: float = param(lo=1e-12, hi=1.0)
    batch_size: int = param(lo=1)
    buffer_size: int = param(lo=1)
    learning_starts: int = param(lo=0)  # transitions in the buffer before the first gradient step
    train_every: int = param(lo=1)  # core steps per gradient step
    gradient_steps: int = param(1, 1, 1000)  # gradient steps each time one is due
    target_update: int = param(lo=1)  # gradient steps between hard target syncs
    eps_start: float = param(lo=0.0, hi=1.0)
    eps_end: float = param(lo=0.0, hi=1.0)
    eps_fraction: float = param(lo=0.0, hi=1.0)  # share of `steps` over which epsilon decays
    huber_delta: float = param(lo=1e-12)
    grad_clip: float = param(lo=1e-12)  # max gradient norm
    hidden: tuple[int, ...] = param(lo=1, hi=65536)  # hidden layer widths
    dueling: bool = param()  # value + advantage head (Wang et al. 2016)
    threads: int = param(lo=1, hi=1024)  # torch CPU threads
    timeout_terminal: bool = param(True)  # a timeout ends the task (no bootstrap), as a crash does
    log_every: int = param(20000, 1)  # transitions between log.csv rows
    checkpoint_every: int = param(200000, 1)  # transitions between checkpoints
    stats_window: int = param(1000, 1)  # episodes in the logged success / crash rates
    # Share of `num_envs` on the multi-AV suites of a mixture (None: rows split evenly over suites).
    multi_av_share: float | None = param(None, 0.0, 1.0)
    # Opt-in observation parts to read (envs/model/observation.py): v2v, which vehicles are AVs and
    # whether they overtake; time_left, the share of the time limit left. The card records them and
    # every evaluation turns them on. Off: every shipped member.
    v2v: bool = param(False)
    time_left: bool = param(False)
    # Model selection (zoo/train/selection.py): every `select_every` transitions from `select_from` on,
    # and at the end, the greedy masked policy on the first `select_scenarios` training scenarios; the
    # best success - crash is shipped (0: no selection, the last network ships). Single-AV suites only.
    select_every: int = param(0, 0)
    select_from: int = param(0, 0)
    select_scenarios: int = param(900, 1)


def observed_parts(hp: DQNHyperparams) -> dict[str, bool]:
    """The opt-in observation parts ``hp`` trains on, as ``with_observation`` keywords."""
    return {part: True for part in OPTIONAL_PARTS if getattr(hp, part)}


# ----------------------------------------------------------------------------- acting
def linear_epsilon(hp: DQNHyperparams, transitions: int) -> float:
    """Epsilon decays linearly from ``eps_start`` to ``eps_end`` over the first ``eps_fraction`` of the steps."""
    frac = min(1.0, transitions / max(1.0, hp.eps_fraction * hp.steps))
    return hp.eps_start + frac * (hp.eps_end - hp.eps_start)


# ----------------------------------------------------------------------------- the training loop
class Trainer:
    """State of one training run; :meth:`run` advances it, :meth:`checkpoint` / :meth:`restore`
    save and reload everything needed to continue (episodes in flight restart on resume)."""

    def __init__(self, algo: str, hp: DQNHyperparams, suites: list[Any], seed: int, name: str | None = None) -> None:
        self.algo, self.hp, self.suites, self.seed = algo, hp, list(suites), int(seed)
        parts = observed_parts(hp)  # the same suites, observed with the opt-in parts
        if parts:
            self.suites = [dataclasses.replace(s, config=s.config.with_observation(**parts)) for s in self.suites]
        self.train_name = name or "+".join(s.name for s in self.suites)
        # Seeding: torch for the network's initial weights, numpy for exploration and replay sampling.
        torch.manual_seed(self.seed)
        torch.set_num_threads(hp.threads)
        self.rng = np.random.default_rng(self.seed)
        self.config = self.suites[0].config  # the observation layout, shared by every training suite
        self.obs_dim = observation_size(self.config)
        self.net = QNetwork(self.obs_dim, hp.hidden, hp.dueling)
        self.target = copy.deepcopy(self.net)
        self.optim = torch.optim.Adam(self.net.parameters(), lr=hp.lr)
        self.buffer = ReplayBuffer(hp.buffer_size, self.obs_dim)
        self.transitions = self.core_steps = self.updates = self.episodes = 0
        self.wall = 0.0
        self.recent: deque[int] = deque(maxlen=hp.stats_window)  # outcomes of the last episodes
        self.last_loss = float("nan")
        self._core_seed = self.seed + 1
        self.nstep: NStepReturns | None = None  # pending n-step transitions (set by _start_core)
        self.multi_av = False  # any training suite with several AVs per road (set by _start_core)
        self.best: dict[str, Any] = {"score": -np.inf, "transitions": None, "net": None}  # model selection
        self.scores: list[list[float]] = []  # [transitions, greedy score] of every scoring, for the card

    def _start_core(self) -> None:
        """The parallel rows: ``num_envs`` split over the training suites, each refilled from its own."""
        pools = [s.scenarios() for s in self.suites]
        sources = [lambda n, rng, pool=pool: pool.take(rng.integers(0, pool.num, n)) for pool in pools]
        rows = row_split(self.hp.num_envs, [p.num_avs for p in pools], self.hp.multi_av_share)
        # A road of E AVs is E rows: each suite gets the roads that fill its rows (at least one).
        roads = [max(1, r // p.num_avs) for r, p in zip(rows, pools, strict=True)]
        self.core = MixedCore([s.config for s in self.suites], sources, roads, seed=self._core_seed)
        self.multi_av = any(p.num_avs > 1 for p in pools)
        if self.multi_av and self.hp.select_every:
            raise TrainError("select_every scores single-AV suites only; set it to 0 for multi-AV training")
        self.select_sets = selection_sets(self.suites, pools, self.hp.select_scenarios)
        self.obs = self._features(self.core.observe())
        # Pending n-step transitions start empty: as episodes in flight, they restart on resume.
        self.nstep = NStepReturns(self.hp.n_step, self.hp.gamma, len(self.obs), self.obs_dim)

    def row_counts(self) -> dict[str, dict[str, int]]:
        """Roads and AV rows each training suite holds in the parallel batch."""
        return {
            s.name: {"roads": n, "rows": c.num}
            for s, n, c in zip(self.suites, self.core.sizes, self.core.cores, strict=True)
        }

    def _features(self, obs: np.ndarray) -> np.ndarray:
        return speed_relative(obs, self.config).astype(np.float32)

    def epsilon(self) -> float:
        return linear_epsilon(self.hp, self.transitions)

    def _choose(self, obs: np.ndarray) -> np.ndarray:
        """Epsilon-greedy over the allowed modes: greedy from the online net, random ones uniform."""
        mask = action_mask(obs, self.config) if self.hp.action_mask else np.ones((len(obs), NUM_MODES), bool)
        with torch.no_grad():
            greedy = masked_argmax(self.net(torch.from_numpy(obs)), torch.from_numpy(mask)).numpy()
        rand = np.argmax(self.rng.random((len(obs), NUM_MODES)) * mask, axis=1)
        explore = self.rng.random(len(obs)) < self.epsilon()
        return np.where(explore, rand, greedy).astype(np.int64)

    def _env_step(self) -> int:
        """One decision of every row, held ``action_repeat`` core steps, stored as transitions;
        returns the core steps taken."""
        act = self._choose(self.obs)
        res = hold(self.core, act, self.hp.action_repeat)
        self.core_steps += res.steps
        obs = self._features(res.obs)
        # A row whose episode ended during the hold: its next obs is the final one, not the refill's.
        finished = res.finished
        next_obs = obs if res.final_obs is None else np.where(finished[:, None], self._features(res.final_obs), obs)
        done = res.terminated | (res.truncated & self.hp.timeout_terminal)
        reward = res.reward.astype(np.float32)
        # Done AVs waiting for their road made no decision: no transition. The others' transitions
        # enter the buffer once complete (at once for one-step targets).
        valid = None if res.waiting is None else ~res.waiting
        assert self.nstep is not None  # (_start_core ran)
        self.buffer.add(**self.nstep.push(self.obs, act, reward, next_obs, done, finished, valid))
        self.transitions += len(act) if valid is None else int(valid.sum())
        if finished.any():
            assert res.final_info is not None  # (set on an auto-reset core when rows finished)
            self.recent.extend(res.final_info["outcome"][finished].tolist())
            self.episodes += int(finished.sum())
        self.obs = obs
        return res.steps

    def _learn(self) -> None:
        """One gradient step on a replay batch: Huber loss to the TD target, clipped, Adam."""
        hp = self.hp
        b = self.buffer.sample(hp.batch_size, self.rng)
        next_mask = torch.from_numpy(action_mask(b["next_obs"], self.config)) if hp.action_mask else None
        obs, action, next_obs = (torch.from_numpy(b[k]) for k in ("obs", "action", "next_obs"))
        gamma = hp.gamma ** torch.from_numpy(b["steps"])  # a k-step transition bootstraps with gamma^k
        y = td_targets(
            self.net,
            self.target,
            torch.from_numpy(b["reward"]),
            next_obs,
            torch.from_numpy(b["done"]),
            gamma,
            hp.double,
            next_mask,
        )
        q = self.net(obs).gather(1, action[:, None])[:, 0]
        loss = nn.functional.huber_loss(q, y, delta=hp.huber_delta)
        self.optim.zero_grad(set_to_none=True)
        loss.backward()
        nn.utils.clip_grad_norm_(self.net.parameters(), hp.grad_clip)
        self.optim.step()
        self.updates += 1
        self.last_loss = float(loss.detach())
        if self.updates % hp.target_update == 0:  # hard target sync
            self.target.load_state_dict(self.net.state_dict())

    def select(self) -> float:
        """Score the greedy masked policy (as the shipped decider acts: float64 numpy, the action
        mask) on the selection scenarios; keep its weights when it beats the best so far."""
        net, use_mask = self.net.to_numpy(), self.hp.action_mask

        def act(obs: np.ndarray, config: Any) -> np.ndarray:
            return numpy_masked_argmax(net(speed_relative(obs, config)), action_mask(obs, config) if use_mask else None)

        score = greedy_score(act, self.select_sets, self.hp.action_repeat)
        self.scores.append([self.transitions, round(score, 4)])
        if score > self.best["score"]:
            self.best = {
                "score": score,
                "transitions": self.transitions,
                "net": {k: v.detach().clone() for k, v in self.net.state_dict().items()},
            }
        return score

    def selection(self) -> dict[str, Any] | None:
        """The card's record of the model selection (None without one)."""
        hp = self.hp
        if not hp.select_every:
            return None
        return {
            "rule": "greedy success rate minus crash rate on the first training scenarios",
            "scenarios": int(sum(sc.num for _, sc in self.select_sets)),
            "every": hp.select_every,
            "from": hp.select_from,
            "transitions": self.best["transitions"],
            "score": round(float(self.best["score"]), 4),
            "scores": self.scores,
        }

    def rates(self) -> tuple[float, float]:
        if not self.recent:
            return float("nan"), float("nan")
        a = np.asarray(self.recent)
        return float((a == SUCCESS).mean()), float((a == CRASH).mean())

    def run(self, steps: int, out: Path | None = None, progress: bool = True) -> None:
        """Act, store, learn until ``steps`` transitions; log, checkpoint and show progress on the way."""
        hp = self.hp
        self._start_core()
        next_log = (self.transitions // hp.log_every + 1) * hp.log_every
        next_ckpt = (self.transitions // hp.checkpoint_every + 1) * hp.checkpoint_every
        every = hp.select_every
        next_select = max(hp.select_from, (self.transitions // every + 1) * every) if every else None
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(
                total=steps,
                initial=min(self.transitions, steps),
                unit="tr",
                desc=self.algo,
                dynamic_ncols=True,
                mininterval=1.0,
            )
        log = _CsvLog(out / RUN_FILES["dqn"][0]) if out else None
        t0 = time.perf_counter() - self.wall
        while self.transitions < steps:
            before, steps_before = self.transitions, self.core_steps
            self._env_step()
            # A gradient step every `train_every` core steps, as many as the hold spanned.
            due = self.core_steps // hp.train_every - steps_before // hp.train_every
            if self.buffer.size >= hp.learning_starts:
                for _ in range(due * hp.gradient_steps):
                    self._learn()
            self.wall = time.perf_counter() - t0
            if bar is not None and self.transitions > before:
                bar.update(min(self.transitions, steps) - min(before, steps))
            if self.transitions >= next_log:
                next_log += hp.log_every
                s, c = self.rates()
                if bar is not None:
                    bar.set_postfix(success=f"{s:.2f}", crash=f"{c:.2f}", eps=f"{self.epsilon():.2f}", refresh=False)
                if log:
                    log.write(
                        {
                            "steps": self.transitions,
                            "episodes": self.episodes,
                            "success_rate": round(s, 4),
                            "crash_rate": round(c, 4),
                            "loss": round(self.last_loss, 5),
                            "epsilon": round(self.epsilon(), 4),
                            "updates": self.updates,
                            "wall_time_s": round(self.wall, 2),
                        }
                    )
            if next_select is not None and self.transitions >= next_select and self.transitions < steps:
                next_select = (self.transitions // every + 1) * every
                score = self.select()
                if bar is not None:
                    bar.write(
                        f"{self.transitions} transitions: greedy success - crash {score:.3f} "
                        f"(best {self.best['score']:.3f} at {self.best['transitions']})"
                    )
            if out and self.transitions >= next_ckpt:
                next_ckpt += hp.checkpoint_every
                self.checkpoint(out / RUN_FILES["dqn"][1])
        if bar is not None:
            bar.close()
        if every and self.best["transitions"] != self.transitions:  # the last network is a candidate too
            self.select()
        if out:
            self.checkpoint(out / RUN_FILES["dqn"][1])

    # ------------------------------------------------------------------------- checkpoints
    def checkpoint(self, path: Path) -> None:
        state = {
            "algo": self.algo,
            "hp": as_dict(self.hp),
            "seed": self.seed,
            "net": self.net.state_dict(),
            "target": self.target.state_dict(),
            "optim": self.optim.state_dict(),
            "counters": [self.transitions, self.core_steps, self.updates, self.episodes],
            "wall": self.wall,
            "recent": list(self.recent),
            "rng": self.rng.bit_generator.state,
            "torch_rng": torch.get_rng_state(),
            "core_seed": self._core_seed + 1,
            "best": {
                "score": float(self.best["score"]),
                "transitions": self.best["transitions"],
                "net": self.best["net"],
            },
            "scores": self.scores,
            "buffer": {
                k: torch.from_numpy(np.ascontiguousarray(v)) if isinstance(v, np.ndarray) else v
                for k, v in self.buffer.state().items()
            },
        }  # tensors: loadable with weights_only
        buf = io.BytesIO()
        torch.save(state, buf)
        atomic_write_bytes(path, buf.getvalue())

    def restore(self, path: str | Path) -> None:
        try:
            # weights_only: tensors and plain containers only; a checkpoint never runs code on resume.
            state = torch.load(path, map_location="cpu", weights_only=True)
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
        self.best = dict(state.get("best") or self.best)
        self.scores = [list(x) for x in state.get("scores", [])]
        self.buffer.load({k: v.numpy() if isinstance(v, torch.Tensor) else v for k, v in state["buffer"].items()})


MULTI_AV_NOTE = (
    "Several automated vehicles (AVs) per road on the multi-AV training suites: every AV row acts "
    "with the one Q-network and its transitions go into the one replay buffer (parameter sharing, "
    "Gupta et al. 2017; the AVs of a road meet copies of the same policy: self-play). An AV that "
    "is done waits frozen until its road ends; its decisions then belong to no episode and are "
    "not stored. multi_av_share of the rows run the multi-AV suites, the rest the single-ego "
    "ones. Everything else is the single-agent DQN trainer's."
)


def row_split(total: int, num_avs: list[int], multi_share: float | None) -> list[int]:
    """Rows per training suite: ``total`` split evenly over the suites, or with ``multi_share`` that
    share split over the multi-AV suites (``num_avs`` > 1) and the rest over the single-AV ones."""
    multi = [i for i, e in enumerate(num_avs) if e > 1]
    single = [i for i, e in enumerate(num_avs) if e == 1]
    if multi_share is None or not multi or not single:
        return split_rows(total, len(num_avs))
    to_multi = int(round(total * multi_share))
    out = [0] * len(num_avs)
    for group, rows in ((multi, to_multi), (single, total - to_multi)):
        for i, n in zip(group, split_rows(rows, len(group)), strict=True):
            out[i] = n
    return out


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


# ----------------------------------------------------------------------------- the card, train
def algorithm(hp: DQNHyperparams, multi_av: bool = False) -> str:
    """The card's ``algorithm``: which DQN, with which head, and parameter sharing when multi-AV."""
    return (
        ("Double DQN (van Hasselt et al. 2016)" if hp.double else "DQN (Mnih et al. 2015)")
        + (" with a dueling head (Wang et al. 2016)" if hp.dueling else "")
        + (f", {hp.n_step}-step returns" if hp.n_step > 1 else "")
        + (", parameters shared by every automated vehicle (Gupta et al. 2017)" if multi_av else "")
    )


def card(trainer: Trainer, hp_file: str) -> dict[str, Any]:
    """The training card of ``trainer``'s network (:func:`.contract.model_card`)."""
    hp, source = trainer.hp, suite_source(trainer.suites, trainer.train_name)
    selection = trainer.selection()
    training = {
        "core_steps": trainer.core_steps,
        "gradient_updates": trainer.updates,
        "episodes": trainer.episodes,
        **({"selection": selection} if selection else {}),
        **({"train_rows": trainer.row_counts(), "multi_av": MULTI_AV_NOTE} if trainer.multi_av else {}),
    }
    return model_card(
        trainer.algo,
        algorithm=algorithm(hp, trainer.multi_av),
        architecture={"kind": "q-network", "dueling": hp.dueling},
        hp=hp,
        hp_file=hp_file,
        action_repeat=hp.action_repeat,
        action_mask=hp.action_mask,
        source=source,
        steps=trainer.transitions,
        steps_unit=STEPS_UNIT,
        seed=trainer.seed,
        wall_time_s=trainer.wall,
        training=training,
        reproduce=reproduce(trainer.algo, source, hp.steps, trainer.seed),
    )


def train(
    suites: list[Any],
    *,
    member: str = "dqn",
    suite_name: str | None = None,
    steps: int | None = None,
    seed: int | None = None,
    out: str | Path | None = None,
    resume: str | Path | None = None,
    hyperparams: str | Path | None = None,
    overrides: dict[str, Any] | None = None,
    progress: bool = True,
) -> Trained:
    """Train ``member`` (dqn, double-dqn, ps-dqn) on the loaded training ``suites`` (``suite_name``:
    the spec they came from, for the card); ``out`` receives ``log.csv``, ``checkpoint.pt``,
    ``<member>.pt``, ``<member>.npz`` and the card ``<member>.json``. ``overrides`` ({"lr": 1e-3})
    go through the same checks as the file (default ``zoo/hyperparams/<member>.toml``)."""
    if member not in members():
        raise TrainError(f"train/dqn.py trains {', '.join(members())}, not {member!r}")
    out_dir = check_writable_dir(out) if out else None  # fail before training, not after it
    hp, hp_file = load_hyperparams(DQNHyperparams, hyperparams or hyperparams_file(member), overrides)
    seed = hp.seed if seed is None else int(seed)
    hp = dataclasses.replace(hp, steps=hp.steps if steps is None else int(steps), seed=seed)
    trainer = Trainer(member, hp, suites, seed, name=suite_name)
    if resume:
        trainer.restore(resume)
    trainer.run(hp.steps, out_dir, progress)
    if trainer.best["net"] is not None:  # model selection: the best greedy network ships
        trainer.net.load_state_dict(trainer.best["net"])
    buf = io.BytesIO()
    torch.save(trainer.net.state_dict(), buf)
    trained = card(trainer, hp_file)
    if observed_parts(hp):
        trained["observation"] = observed_parts(hp)  # (zoo/members/learned.py declared_config reads it)
    return finish(trained, weights=buf.getvalue(), module=trainer.net, out=out_dir)
