"""A compact PPO in numpy, the trainer ``ppo-numpy`` (``overtakezoo train ppo-numpy``, hyperparameters
``zoo/hyperparams/ppo-numpy.toml``): the fast path to a ppo-like policy, beside rsl-rl's (:mod:`.ppo`,
``overtakezoo train ppo``, which the shipped ppo member is trained with and which stays the reference
PPO). It is a trainer of its own, not a zoo member (:data:`.contract.TRAINERS`): its runs are named
``ppo-numpy``, never ``ppo``.

Why hand-written and not rsl-rl / torch: importing torch (and tensordict, which pulls in
torch._dynamo) costs ~2-3 CPU s per process, more than this whole trainer needs to reach the paper's
level on table1-train, and the networks are two 64-wide layers, for which numpy's float64 matrix
products are as fast as torch's. The algorithm is PPO's clipped surrogate with GAE (Schulman et al.
2017, "Proximal Policy Optimization Algorithms", arXiv:1707.06347; Schulman et al. 2016, GAE,
arXiv:1506.02438), minibatch advantage normalisation, an entropy bonus and Adam (Kingma & Ba 2015),
with a global gradient-norm clip, as in the usual implementations (e.g. CleanRL's ppo.py).

It steps the same cores as every trainer (:class:`~overtakezoo.envs.mixture.MixedCore`, the decision
held ``action_repeat`` core steps by :func:`~overtakezoo.envs.hold.hold`), learns from the env's
reward, and writes what the zoo loads: ``ppo-numpy.npz`` (the actor as a :class:`NumpyMLP`) and the
card ``ppo-numpy.json`` (no torch weights file; ``eval --policy`` and ``load_pretrained`` read them).
Every random draw comes from one seeded numpy generator and the matrix products run on one BLAS
thread, so the same seed gives the same bits.
"""

from __future__ import annotations

import csv
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from overtakezoo.envs import CRASH, SUCCESS, TIMEOUT, observation_size
from overtakezoo.envs.io import check_writable_dir
from overtakezoo.zoo.members.features import speed_relative
from overtakezoo.zoo.train.contract import (
    RUN_FILES,
    TrainError,
    hyperparams_file,
    load_hyperparams,
    read_hyperparams,
    refuse_other_trainers,
)
from overtakezoo.zoo.train.typed import HyperparameterError, param

NAME = "ppo-numpy"  # the trainer's name (contract.TRAINERS): its runs' files, cards and results
LEARNS_FROM = "suites"  # what train() takes: loaded training suites
STEPS_UNIT = "decisions (env steps)"
ALGORITHM = (
    "PPO (Schulman et al. 2017: clipped surrogate, GAE, minibatch advantage normalisation, Adam), "
    "numpy (overtakezoo.zoo.train.fastppo)"
)
# float32 for the networks (training only; what ships is float64, NumpyMLP): half the CPU time of
# float64 in the update, and the same bits on every run (one BLAS thread).
DTYPE = np.float32
LOG_COLUMNS = [
    "iteration",
    "env_steps",
    "wall_s",
    "episodes",
    "success_rate",
    "crash_rate",
    "timeout_rate",
    "greedy_score",
]


# ----------------------------------------------------------------------------- hyperparameters
@dataclass(frozen=True)
class TrainSection:
    steps: int = param(lo=1)  # decisions (num_envs * num_steps_per_env per iteration)
    select_every: int = param(0, 0)  # iterations between greedy scorings (0: only the last); the best is kept
    select_from: int = param(0, 0)  # first iteration scored (earlier policies are not candidates)
    select_scenarios: int = param(256, 1)  # training scenarios the greedy policy is scored on


@dataclass(frozen=True)
class EnvSection:
    num_envs: int = param(lo=1, hi=1_000_000)
    action_repeat: int = param(10, 1, 1000)


@dataclass(frozen=True)
class PPOSection:
    num_steps_per_env: int = param(lo=1)
    epochs: int = param(lo=1)
    minibatches: int = param(lo=1)
    clip: float = param(0.2, 0.0, 10.0)
    gamma: float = param(0.99, 0.0, 1.0)
    lam: float = param(0.95, 0.0, 1.0)
    learning_rate: float = param(lo=0.0, hi=1.0)
    entropy_coef: float = param(0.0, 0.0, 10.0)
    value_coef: float = param(0.5, 0.0, 100.0)
    max_grad_norm: float = param(1.0, 0.0)
    hidden: tuple[int, ...] = param(lo=1, hi=4096)  # hidden layer widths (tanh)
    overtake_bias: float = param(0.0, -10.0, 10.0)  # initial logit of OVERTAKE over the others (exploration)


@dataclass(frozen=True)
class FastPPOHyperparams:
    train: TrainSection = param()
    env: EnvSection = param()
    ppo: PPOSection = param()


# ----------------------------------------------------------------------------- networks
class MLP:
    """tanh MLP with parameters in torch's ``nn.Linear`` layout (W (out, in), b (out,)), its
    backward pass and Adam state."""

    def __init__(self, sizes: list[int], rng: np.random.Generator, last_gain: float) -> None:
        self.params: list[np.ndarray] = []
        for i, (n_in, n_out) in enumerate(zip(sizes[:-1], sizes[1:], strict=True)):
            gain = last_gain if i == len(sizes) - 2 else math.sqrt(2.0)
            self.params += [_orthogonal(rng, n_out, n_in, gain).astype(DTYPE), np.zeros(n_out, DTYPE)]
        self.m = [np.zeros_like(p) for p in self.params]
        self.v = [np.zeros_like(p) for p in self.params]
        self.t = 0

    def forward(self, x: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
        acts, h = [x], x
        last = len(self.params) // 2 - 1
        for i in range(last + 1):
            h = h @ self.params[2 * i].T + self.params[2 * i + 1]
            if i < last:
                h = np.tanh(h)
            acts.append(h)
        return h, acts

    def backward(self, acts: list[np.ndarray], dout: np.ndarray) -> list[np.ndarray]:
        grads: list[np.ndarray] = [np.empty(0)] * len(self.params)
        d = dout
        for i in range(len(self.params) // 2 - 1, -1, -1):
            grads[2 * i], grads[2 * i + 1] = d.T @ acts[i], d.sum(axis=0)
            if i:
                d = (d @ self.params[2 * i]) * (1.0 - acts[i] ** 2)
        return grads

    def adam(self, grads: list[np.ndarray], lr: float, b1: float = 0.9, b2: float = 0.999, eps: float = 1e-8) -> None:
        self.t += 1
        c1, c2 = 1.0 - b1**self.t, 1.0 - b2**self.t
        for p, g, m, v in zip(self.params, grads, self.m, self.v, strict=True):
            m *= b1
            m += (1.0 - b1) * g
            v *= b2
            v += (1.0 - b2) * g * g
            p -= lr * (m / c1) / (np.sqrt(v / c2) + eps)

    def layers(self) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
        return tuple(
            (self.params[i].astype(np.float64), self.params[i + 1].astype(np.float64))
            for i in range(0, len(self.params), 2)
        )


def _orthogonal(rng: np.random.Generator, rows: int, cols: int, gain: float) -> np.ndarray:
    """Orthogonal initialisation (Saxe et al. 2014), the usual one for PPO's layers."""
    a = rng.standard_normal((max(rows, cols), min(rows, cols)))
    q, r = np.linalg.qr(a)
    q = q * np.sign(np.diag(r))
    return gain * (q if rows >= cols else q.T)[:rows, :cols]


def log_softmax(z: np.ndarray) -> np.ndarray:
    z = z - z.max(axis=1, keepdims=True)
    return z - np.log(np.exp(z).sum(axis=1, keepdims=True))


def sample(logp: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One categorical draw per row (inverse CDF of one uniform per row)."""
    cdf = np.cumsum(np.exp(logp), axis=1)
    u = rng.random(len(logp))[:, None] * cdf[:, -1:]
    return np.minimum((cdf < u).sum(axis=1), logp.shape[1] - 1).astype(np.int64)


# ----------------------------------------------------------------------------- the update
def update(actor: MLP, critic: MLP, batch: dict[str, np.ndarray], p: PPOSection, rng: np.random.Generator) -> None:
    """PPO's epochs of minibatch steps on one iteration's ``batch`` (obs, act, logp, adv, ret)."""
    n = len(batch["act"])
    size = max(1, n // p.minibatches)
    for _ in range(p.epochs):
        order = rng.permutation(n)
        for k in range(p.minibatches):
            idx = order[k * size : (k + 1) * size]
            x, a, old, adv, ret = (batch[key][idx] for key in ("obs", "act", "logp", "adv", "ret"))
            b = len(idx)
            adv = (adv - adv.mean()) / (adv.std() + 1e-8)
            logits, acts_a = actor.forward(x)
            logp = log_softmax(logits)
            prob = np.exp(logp)
            ratio = np.exp(logp[np.arange(b), a] - old)
            unclipped = ratio * adv <= np.clip(ratio, 1.0 - p.clip, 1.0 + p.clip) * adv
            # d(-min(r A, clip(r) A)) / d logp[a] = -A r where the unclipped term is the minimum
            g_logp_a = np.where(unclipped, -adv * ratio, 0.0) / b
            onehot = np.zeros_like(logits)
            onehot[np.arange(b), a] = 1.0
            entropy = -(prob * logp).sum(axis=1, keepdims=True)
            d_logits = g_logp_a[:, None] * (onehot - prob) + p.entropy_coef / b * prob * (logp + entropy)
            value, acts_c = critic.forward(x)
            d_value = 2.0 * p.value_coef * (value[:, 0] - ret)[:, None] / b
            ga, gc = actor.backward(acts_a, d_logits), critic.backward(acts_c, d_value)
            norm = math.sqrt(sum(float((g * g).sum()) for g in ga + gc))
            if p.max_grad_norm > 0 and norm > p.max_grad_norm:
                scale = p.max_grad_norm / (norm + 1e-6)
                ga, gc = [g * scale for g in ga], [g * scale for g in gc]
            actor.adam(ga, p.learning_rate)
            critic.adam(gc, p.learning_rate)


def gae(
    reward: np.ndarray, value: np.ndarray, done: np.ndarray, last: np.ndarray, gamma: float, lam: float
) -> tuple[np.ndarray, np.ndarray]:
    """(T, N) advantages and returns; a finished row (any outcome, timeouts included: the limit is
    part of the task) does not bootstrap."""
    adv = np.zeros_like(reward)
    running = np.zeros(reward.shape[1])
    nxt = last
    for t in range(len(reward) - 1, -1, -1):  # over time only: each step is vectorized over rows
        live = 1.0 - done[t]
        delta = reward[t] + gamma * nxt * live - value[t]
        running = delta + gamma * lam * live * running
        adv[t], nxt = running, value[t]
    return adv, adv + value


# ----------------------------------------------------------------------------- training
def train(
    suites: list[Any],
    *,
    member: str = NAME,
    suite_name: str | None = None,
    steps: int | None = None,
    seed: int | None = None,
    out: str | Path | None = None,
    resume: str | Path | None = None,
    hyperparams: str | Path | None = None,
    overrides: dict[str, Any] | None = None,
    progress: bool = True,
    device: str | None = None,
) -> Any:
    """Train on the loaded training ``suites`` (``suite_name``: the spec they came from) for ``steps``
    decisions, seed ``seed`` (default 0), hyperparameters ``hyperparams`` (default
    ``zoo/hyperparams/ppo-numpy.toml``) with ``overrides``; write ``train_log.csv``, ``ppo-numpy.npz``
    and ``ppo-numpy.json`` into ``out`` (default ``runs/ppo-numpy-seed<seed>``); return the
    :class:`~.contract.Trained` run. No checkpoints, so no ``resume``. ``device`` (cuda, cuda:N, or cpu
    for the torch path on the CPU): the same recipe in torch on that device (:mod:`.devppo`)."""
    from threadpoolctl import threadpool_limits

    if member != NAME:
        raise TrainError(f"train/fastppo.py trains {NAME}, not {member!r}")
    if resume is not None:
        raise TrainError(f"--resume: {NAME} keeps no checkpoints")
    path = hyperparams or hyperparams_file(NAME)
    refuse_other_trainers(path, NAME, {"ppo": ("runner", "algorithm", "actor", "critic")})
    if "trainer" in read_hyperparams(path):  # (a file from before ppo-numpy had its own name)
        raise HyperparameterError(
            f"{path}: trainer: not a key: the numpy PPO is a trainer of its own, `overtakezoo train {NAME}`; "
            "delete the line"
        )
    hp, hp_file = load_hyperparams(FastPPOHyperparams, path, overrides)
    seed = 0 if seed is None else int(seed)
    out = Path(out) if out is not None else Path("runs") / f"{NAME}-seed{seed}"
    if device is not None:
        from overtakezoo.zoo.train.devppo import train_on_device

        with threadpool_limits(limits=1, user_api="blas"):  # (the host's selection runs: same bits)
            return train_on_device(
                suites,
                hp,
                hp_file,
                suite_name=suite_name,
                steps=steps,
                seed=seed,
                out=out,
                progress=progress,
                device=device,
            )
    with threadpool_limits(limits=1, user_api="blas"):  # same bits on any core count (and faster here)
        return _train(suites, hp, hp_file, suite_name=suite_name, steps=steps, seed=seed, out=out, progress=progress)


class Run:
    """What the numpy trainer and the device one (:mod:`.devppo`) share: a run's plan (iterations,
    the training pools, the first weights' generator), its model selection and its log."""

    def __init__(
        self, suites: list[Any], hp: FastPPOHyperparams, *, suite_name: str | None, steps: int | None, seed: int
    ) -> None:
        from overtakezoo.zoo.train.contract import suite_source
        from overtakezoo.zoo.train.selection import selection_sets

        self.hp, self.p, self.n, self.repeat = hp, hp.ppo, hp.env.num_envs, hp.env.action_repeat
        self.asked = int(steps if steps is not None else hp.train.steps)
        self.per_iter = self.n * self.p.num_steps_per_env
        self.iterations = max(1, math.ceil(self.asked / self.per_iter))
        self.seed = seed
        self.rng = np.random.default_rng(np.random.SeedSequence([seed, 1]))  # weights, draws, minibatches
        self.source = suite_source(suites, suite_name)
        self.config = suites[0].config
        self.dim = observation_size(self.config)
        self.pools = [s.scenarios() for s in suites]
        multi = [s.name for s, q in zip(suites, self.pools, strict=True) if q.num_avs > 1]
        if multi:  # (waiting AVs of a multi-AV road would need their transitions dropped; rsl-rl's face has none)
            raise TrainError(f"{NAME} trains single-AV suites; {', '.join(multi)} has several AVs per road")
        self.select_sets = selection_sets(suites, self.pools, hp.train.select_scenarios)
        self.best: dict[str, Any] = {"score": -np.inf, "iteration": None, "layers": None}
        self.log_rows: list[list[Any]] = []
        self.cpu = {"rollout": 0.0, "update": 0.0, "select": 0.0}  # process CPU seconds by phase (on the card)
        self.t0 = time.perf_counter()

    def networks(self) -> tuple[MLP, MLP]:
        """The initial actor (its OVERTAKE logit biased: start near always-overtake) and critic."""
        p = self.p
        actor = MLP([self.dim, *p.hidden, 3], self.rng, 0.01)
        actor.params[-1][1] += p.overtake_bias
        return actor, MLP([self.dim, *p.hidden, 1], self.rng, 1.0)

    def select(self, it: int, layers: Any) -> float | None:
        """Score the greedy policy of ``layers()`` after iteration ``it`` (0-based) when selection is
        due then, keeping the best; its score, or None when not due."""
        from overtakezoo.zoo.members.mlp import NumpyMLP
        from overtakezoo.zoo.train.selection import greedy_score

        every, done = self.hp.train.select_every, it + 1
        if not (done == self.iterations or (every and done % every == 0 and done >= self.hp.train.select_from)):
            return None
        c0 = time.process_time()
        chosen = layers()
        net = NumpyMLP(chosen, "tanh")

        def greedy(o: np.ndarray, c: Any) -> np.ndarray:
            return net(speed_relative(o, c)).argmax(axis=1)

        score = greedy_score(greedy, self.select_sets, self.repeat)
        if score > self.best["score"]:
            self.best = {"score": score, "iteration": done, "layers": chosen}
        self.cpu["select"] += time.process_time() - c0
        return score

    def log(self, it: int, counts: list[int], score: float | None, progress: bool, where: str = "") -> None:
        """Iteration ``it``'s row of train_log.csv from its (episodes, successes, crashes, timeouts)."""
        episodes, success, crash, timeout = (int(c) for c in counts)
        eps = max(episodes, 1)
        self.log_rows.append(
            [
                it + 1,
                (it + 1) * self.per_iter,
                f"{time.perf_counter() - self.t0:.2f}",
                episodes,
                f"{success / eps:.4f}",
                f"{crash / eps:.4f}",
                f"{timeout / eps:.4f}",
                "" if score is None else f"{score:.4f}",
            ]
        )
        if progress:
            print(
                f"{NAME}{where} iteration {it + 1}/{self.iterations}: "
                f"success {success / eps:.2f} crash {crash / eps:.2f}"
                + ("" if score is None else f", greedy score {score:.3f}"),
                flush=True,
            )

    def finish(self, hp_file: str, out: Path, device: str | None = None) -> Any:
        """Write the log, the weights and the card (_finish); the Trained run."""
        wall = time.perf_counter() - self.t0
        write_log(out, [LOG_COLUMNS, *self.log_rows])
        return _finish(
            self.best,
            self.hp,
            hp_file,
            self.source,
            self.iterations * self.per_iter,
            self.seed,
            wall,
            self.iterations,
            self.select_sets,
            out,
            self.asked,
            {k: round(v, 3) for k, v in self.cpu.items()},
            device=device,
        )


def _train(
    suites: list[Any],
    hp: FastPPOHyperparams,
    hp_file: str,
    *,
    suite_name: str | None,
    steps: int | None,
    seed: int,
    out: Path,
    progress: bool,
) -> Any:
    from overtakezoo.envs.hold import hold
    from overtakezoo.envs.mixture import MixedCore, split_rows

    check_writable_dir(out)
    run = Run(suites, hp, suite_name=suite_name, steps=steps, seed=seed)
    p, n, repeat, dim, rng, config = run.p, run.n, run.repeat, run.dim, run.rng, run.config

    def pool_source(pool: Any) -> Any:  # rows drawn uniformly from the suite (rsl_rl.pool_source, without torch)
        return lambda k, g: pool.take(g.integers(0, pool.num, k))

    core = MixedCore(
        [s.config for s in suites], [pool_source(q) for q in run.pools], split_rows(n, len(run.pools)), seed=seed
    )
    actor, critic = run.networks()
    obs = speed_relative(core.observe(), config).astype(DTYPE)
    clock = time.process_time
    for it in range(run.iterations):
        T = p.num_steps_per_env
        b_obs, b_act = np.empty((T, n, dim), DTYPE), np.empty((T, n), np.int64)
        b_logp, b_val, b_rew, b_done = (np.empty((T, n)) for _ in range(4))
        counts = np.zeros(4, np.int64)  # episodes, successes, crashes, timeouts
        c0 = clock()
        for t in range(T):
            logits, _ = actor.forward(obs)
            logp = log_softmax(logits)
            act = sample(logp, rng)
            b_obs[t], b_act[t], b_logp[t] = obs, act, logp[np.arange(n), act]
            b_val[t] = critic.forward(obs)[0][:, 0]
            res = hold(core, act, repeat)
            b_rew[t], b_done[t] = res.reward, res.finished
            if res.finished.any():
                assert res.final_info is not None  # (set on an auto-reset core when rows finished)
                outcome = res.final_info["outcome"][res.finished]
                counts += [
                    len(outcome),
                    (outcome == SUCCESS).sum(),
                    (outcome == CRASH).sum(),
                    (outcome == TIMEOUT).sum(),
                ]
            obs = speed_relative(res.obs, config).astype(DTYPE)
        c1 = clock()
        adv, ret = gae(b_rew, b_val, b_done, critic.forward(obs)[0][:, 0], p.gamma, p.lam)
        batch: dict[str, np.ndarray] = {
            "obs": b_obs.reshape(-1, dim),
            "act": b_act.reshape(-1),
            "logp": b_logp.reshape(-1).astype(DTYPE),
            "adv": adv.reshape(-1).astype(DTYPE),
            "ret": ret.reshape(-1).astype(DTYPE),
        }
        update(actor, critic, batch, p, rng)
        run.cpu["rollout"] += c1 - c0
        run.cpu["update"] += clock() - c1
        run.log(it, counts.tolist(), run.select(it, actor.layers), progress)
    return run.finish(hp_file, out)


def write_log(out: Path, rows: list[list[Any]]) -> None:
    """The run's ``train_log.csv`` (one row per iteration, under LOG_COLUMNS)."""
    with open(out / RUN_FILES["fastppo"][0], "w", newline="") as f:
        csv.writer(f).writerows(rows)


def _finish(
    best: dict[str, Any],
    hp: FastPPOHyperparams,
    hp_file: str,
    source: dict[str, Any],
    steps: int,
    seed: int,
    wall: float,
    iterations: int,
    select_sets: list,
    out: Path,
    asked: int,
    cpu: dict[str, float],
    device: str | None = None,
) -> Any:
    """The model card and files of a finished run; ``device``: the run was devppo's (torch on it)."""
    from overtakezoo.zoo.members.mlp import NumpyMLP, npz_bytes, read_npz
    from overtakezoo.zoo.train.contract import Trained, model_card, reproduce, write_outputs
    from overtakezoo.zoo.train.export import npz_card

    npz = npz_bytes(NumpyMLP(best["layers"], "tanh").arrays())
    net = NumpyMLP.from_arrays(read_npz(npz), "tanh")  # exactly what the file holds
    selection = {
        "rule": "greedy success rate minus crash rate on the first training scenarios",
        "scenarios": int(sum(sc.num for _, sc in select_sets)),
        "every": hp.train.select_every,
        "from": hp.train.select_from,
        "iteration": best["iteration"],
        "score": round(best["score"], 4),
    }
    card = model_card(
        NAME,
        algorithm=ALGORITHM,
        architecture={"kind": "policy"},
        hp=hp,
        hp_file=hp_file,
        action_repeat=hp.env.action_repeat,
        action_mask=False,
        source=source,
        steps=steps,
        steps_unit=STEPS_UNIT,
        seed=seed,
        wall_time_s=wall,
        training={
            "iterations": iterations,
            "selection": selection,
            "trainer": "fastppo (numpy)" if device is None else f"devppo (torch, {device})",
            "cpu_s": cpu,
        },
        # (model_card adds --hyperparams and --set where needed)
        reproduce=reproduce(NAME, source, asked, seed) + (_device_flags(device) if device else ""),
        versions={"numpy": np.__version__, **({"torch": _torch_version()} if device else {})},
        torch=False,
    )
    trained = Trained(npz_card(card, net, npz, NAME), npz, net)
    write_outputs(out, trained)
    return trained


def _device_flags(device: str) -> str:
    return f" --device {device}" + (" --backend torch" if device == "cpu" else "")


def _torch_version() -> str:
    import torch

    return str(torch.__version__)
