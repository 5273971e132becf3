"""DAgger (the ``dagger`` member): the privileged oracle distilled into an observation-only student.

Dataset Aggregation (Ross, Gordon & Bagnell 2011, "A Reduction of Imitation Learning and Structured
Prediction to No-Regret Online Learning"), with the privileged teacher of "Learning by Cheating"
(Chen et al. 2019): the teacher (:class:`overtakezoo.zoo.members.oracle.Oracle`) sees the whole
simulator state, the student only the observation. Reads top to bottom: the hyperparameters
(``zoo/hyperparams/dagger.toml``), the student's acting, the rollouts that the oracle labels, the
fit, the choice of the decision threshold, the outputs.

On training splits with several automated vehicles per road (``duel-train``, ``platoon-train``,
``mixed-traffic-train``) the teacher is the joint oracle
(:class:`overtakezoo.zoo.members.joint_oracle.JointOracle`), which plans every AV of a road together;
each AV row is a state labelled with its own mode of the road's best joint plan, and one student
drives every seat (parameter sharing, as ``ps-dqn``).

Each iteration ``i``:

1. **Roll out** ``episodes`` training scenarios per training split (drawn from the split's own
   pool) under the mixture policy of Ross et al.: at each decision a row follows the oracle with
   probability ``beta_i = beta * beta_decay**i`` and the current student otherwise (``beta_i`` is 1
   at the first iteration: the first data are the oracle's own trajectories).
2. **Label** every decision state the rows visit with the oracle's decision *at that state*: the
   oracle is bound to the live core and, at every decision, clones every running row and simulates
   "overtake now and hold" to the end (``trust_verified`` off: the student may have left the
   oracle's plan, so nothing verified earlier is taken on trust). All rows of a split in one batch.
3. **Aggregate** the (features, label) pairs with every earlier iteration's and **fit** the
   classifier on all of them (warm-started, ``grad_steps`` minibatches of cross-entropy, Adam).

The score's asymmetry: a crash costs two successes, and the oracle's OVERTAKE means "overtaking now
succeeds given the hidden future", which the student cannot always tell from what it sees. So after
the last fit an offset on the OVERTAKE logit (a decision threshold on the odds of overtaking) is
chosen from ``offsets`` by the OvertakeZoo score (success - 2 x crash, mean over splits) on the first
``select_scenarios`` scenarios of every *training* split, all offsets in one batch; it is baked into
the exported network's last bias, so the member acts as every learned member does (argmax over the
modes the action mask allows, each decision held ``action_repeat`` core steps). Test suites never
enter any choice.

Everything is seeded (numpy for scenario draws, the beta mixture and minibatches; torch for the
initial weights), torch on ``threads`` threads: the same seed gives the same bytes. ``steps`` are
DAgger iterations. :func:`train` returns the :class:`~.contract.Trained` member and writes
``log.csv``, ``dagger.npz`` and ``dagger.json`` into ``out``.

    overtakezoo train dagger --suite core-train --seeds 0,1,2 --out runs/dagger
"""

from __future__ import annotations

import copy
import csv
import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from overtakezoo.envs import CRASH, OVERTAKE, SUCCESS, observation_size
from overtakezoo.envs.core import OvertakeCore
from overtakezoo.envs.hold import hold, hold_steps
from overtakezoo.envs.io import check_writable_dir
from overtakezoo.zoo.members.features import speed_relative
from overtakezoo.zoo.members.joint_oracle import JointOracle
from overtakezoo.zoo.members.learned import action_mask, masked_argmax
from overtakezoo.zoo.members.oracle import Oracle
from overtakezoo.zoo.train.bc import cross_entropy_step
from overtakezoo.zoo.train.contract import (
    Trained,
    TrainError,
    finish,
    hyperparams_file,
    load_hyperparams,
    model_card,
    reproduce,
    suite_source,
)
from overtakezoo.zoo.train.qlearning import QNetwork  # the zoo's torch MLP (Linear / ReLU layers)
from overtakezoo.zoo.train.typed import param

LEARNS_FROM = "suites"
ALGORITHM = (
    "DAgger (Ross et al. 2011) distilling the privileged oracle into an observation-only classifier "
    "('learning by cheating', Chen et al. 2019), OVERTAKE threshold chosen on the training splits"
)
STEPS_UNIT = "DAgger iterations"


@dataclass(frozen=True)
class DAggerHyperparams:
    """``zoo/hyperparams/dagger.toml`` (the comments there say why each value)."""

    seed: int = param(0, 0, 2**31 - 1)
    steps: int = param(6, 1, 1000)  # DAgger iterations
    episodes: int = param(128, 1, 1 << 20)  # scenarios rolled out per training split per iteration
    label_share: float = param(0.5, 0.0, 1.0)  # share of the student's own decisions the oracle labels
    beta: float = param(1.0, 0.0, 1.0)  # probability of the oracle's mode at iteration 0
    beta_decay: float = param(0.5, 0.0, 1.0)  # beta_i = beta * beta_decay**i
    grad_steps: int = param(1500, 1, 10**7)  # minibatches per fit (warm-started each iteration)
    batch_size: int = param(1024, 1, 1 << 20)
    lr: float = param(1e-3, 1e-7, 1.0)
    weight_decay: float = param(0.0, 0.0, 1.0)
    hidden: tuple[int, ...] = param((128, 128), 1, 4096)
    action_repeat: int = param(10, 1, 1000)  # core steps each decision is held (the oracle re-plans as often)
    action_mask: bool = param(True)  # act among the modes the mode-transition mask allows
    frame_stack: int = param(1, 1, 64)  # decisions of observations the student reads (memory; 1: none)
    offsets: tuple[float, ...] = param((-3.0, -2.0, -1.5, -1.0, -0.5, 0.0, 0.5), -50.0, 50.0)  # OVERTAKE logit
    select_scenarios: int = param(300, 1, 1 << 20)  # first scenarios of each training split for the threshold
    threads: int = param(1, 1, 256)


# ----------------------------------------------------------------------------- the student
def features(obs: np.ndarray, config: Any) -> np.ndarray:
    return speed_relative(obs, config).astype(np.float32)


class History:
    """The student's input: the features of each row's last ``k`` decisions, newest first, zeros
    before its episode began (k = 1: the current observation's features alone)."""

    def __init__(self, n: int, k: int, config: Any) -> None:
        self.config, self.k = config, k
        self.frames = np.zeros((n, k, observation_size(config)), np.float32)

    def push(self, obs: np.ndarray) -> np.ndarray:
        f = features(obs, self.config)
        if self.k == 1:
            return f
        self.frames = np.concatenate([f[:, None], self.frames[:, :-1]], axis=1)
        return self.frames.reshape(len(f), -1)


def student_modes(
    net: nn.Module, x: np.ndarray, obs: np.ndarray, config: Any, offset: np.ndarray | float, masked: bool
) -> np.ndarray:
    """The student's modes on input ``x`` (:class:`History`): argmax of its logits, ``offset`` added
    to OVERTAKE's, over the modes the observations ``obs`` allow."""
    with torch.no_grad():
        logits = net(torch.from_numpy(x)).double().numpy()
    logits[:, OVERTAKE] += offset
    return masked_argmax(logits, action_mask(obs, config) if masked else None)


# ----------------------------------------------------------------------------- rollouts the oracle labels
def teacher(core: OvertakeCore, config: Any, hp: DAggerHyperparams, trust_verified: bool) -> Oracle | JointOracle:
    """The privileged teacher bound to ``core``: the oracle on single-AV roads; on roads with several
    AVs the joint oracle, which plans every AV of a road together (each AV row is labelled with its
    own mode of the road's best joint plan, so one student learns every seat: parameter sharing)."""
    kind = JointOracle if core.num_avs > 1 else Oracle
    oracle = kind(config, replan_s=hp.action_repeat * config.dt, trust_verified=trust_verified)
    oracle.bind(core)
    return oracle


def rollout(
    suite: Any, scenarios: Any, net: nn.Module | None, beta: float, hp: DAggerHyperparams, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``scenarios`` of ``suite`` driven by the beta-mixture of oracle and student (``net``; None:
    the oracle alone), every running row's decision state labelled by the oracle. Returns the
    features (M, D), the labels (M,) and each row's outcome."""
    config = suite.config
    core = OvertakeCore(config)
    obs = core.reset(scenarios)
    # The oracle alone may trust its verified overtakes (it drives them); a student may leave them.
    oracle = teacher(core, config, hp, trust_verified=net is None)
    steps = hold_steps(config.decision_interval, hp.action_repeat)
    xs, ys = [], []
    history = History(core.num, hp.frame_stack, config)
    while not core.done.all():
        live = ~np.asarray(core.done)
        x = history.push(obs)
        if net is None:  # the oracle drives: every running row is labelled by its own decision
            modes = oracle.act_batch(obs)
            labelled = live
        else:
            # Rows driven by the oracle this decision (probability beta) need its label; of the
            # others a random label_share is labelled too (the states the student drove to).
            by_oracle = rng.random(len(live)) < beta
            labelled = live & (by_oracle | (rng.random(len(live)) < hp.label_share))
            oracle.plan(np.flatnonzero(labelled))
            own = student_modes(net, x, obs, config, 0.0, hp.action_mask)
            modes = np.where(by_oracle, oracle.decision, own)
        if labelled.any():
            xs.append(x[labelled])
            ys.append(oracle.decision[labelled].copy())
        obs = hold(core, modes, steps).obs
    return np.concatenate(xs), np.concatenate(ys), np.asarray(core.outcome).copy()


# ----------------------------------------------------------------------------- the fit
def fit(
    net: nn.Module,
    optim: torch.optim.Optimizer,
    x: torch.Tensor,
    y: torch.Tensor,
    hp: DAggerHyperparams,
    rng: np.random.Generator,
) -> float:
    """``grad_steps`` minibatches of cross-entropy on the aggregated data; returns the last loss."""
    net.train()
    loss = torch.zeros(())
    for _ in range(hp.grad_steps):
        loss = cross_entropy_step(net, optim, x, y, rng, hp.batch_size)
    net.eval()
    return float(loss.detach())


# ----------------------------------------------------------------------------- the threshold
def select_offset(net: nn.Module, suites: list[Any], hp: DAggerHyperparams) -> tuple[float, dict[str, Any]]:
    """The OVERTAKE logit offset with the best OvertakeZoo score on the first ``select_scenarios``
    of every training split (every offset on a copy of those scenarios, one batch per split); ties
    go to the offset nearest 0. On multi-AV splits a road counts as the board counts it: a success
    when every AV of it succeeds, a crash when any crashes. Returns it with every offset's per-split
    success and crash rates."""
    offsets = np.asarray(hp.offsets, np.float64)
    k = len(offsets)
    table: dict[str, Any] = {}
    scores = np.zeros(k)
    for suite in suites:
        config = suite.config
        n = min(hp.select_scenarios, suite.count)
        sc = suite.scenarios().take(np.tile(np.arange(n), k))  # row j * n + i: scenario i, offset j
        core = OvertakeCore(config)
        obs = core.reset(sc)
        row_offset = np.tile(np.repeat(offsets, n), core.num_avs)  # AV-major rows: e * roads + road
        steps = hold_steps(config.decision_interval, hp.action_repeat)
        history = History(core.num, hp.frame_stack, config)
        while not core.done.all():
            x = history.push(obs)
            obs = hold(core, student_modes(net, x, obs, config, row_offset, hp.action_mask), steps).obs
        outcome = np.asarray(core.outcome).reshape(core.num_avs, k, n)
        succ = (outcome == SUCCESS).all(axis=0).mean(1)
        crash = (outcome == CRASH).any(axis=0).mean(1)
        scores += (succ - 2 * crash) / len(suites)
        table[suite.name] = {"success_rate": succ.tolist(), "crash_rate": crash.tolist()}
    best = max(range(k), key=lambda j: (round(float(scores[j]), 12), -abs(offsets[j])))
    return float(offsets[best]), {"offsets": offsets.tolist(), "score": scores.tolist(), "per_split": table}


# ----------------------------------------------------------------------------- the loop
def run(
    suites: list[Any], hp: DAggerHyperparams, out: Path | None, progress: bool
) -> tuple[QNetwork, float, dict[str, Any]]:
    torch.manual_seed(hp.seed)
    torch.set_num_threads(hp.threads)
    rng = np.random.default_rng(hp.seed)
    config = suites[0].config
    net = QNetwork(hp.frame_stack * observation_size(config), hp.hidden, dueling=False)  # logits over the modes
    net.eval()
    optim = torch.optim.Adam(net.parameters(), lr=hp.lr, weight_decay=hp.weight_decay)
    xs: list[np.ndarray] = []
    ys: list[np.ndarray] = []
    log: list[dict[str, Any]] = []
    pools = [s.scenarios() for s in suites]
    t0, cpu0 = time.perf_counter(), time.process_time()
    for it in range(hp.steps):
        beta = hp.beta * hp.beta_decay**it
        t_roll = time.process_time()
        outcomes = []
        for suite, pool in zip(suites, pools, strict=True):
            scenarios = pool.take(rng.integers(0, pool.num, hp.episodes))
            x, y, outcome = rollout(suite, scenarios, net if it and beta < 1.0 else None, beta, hp, rng)
            xs.append(x)
            ys.append(y)
            outcomes.append(outcome)
        t_fit = time.process_time()
        x_all, y_all = torch.from_numpy(np.concatenate(xs)), torch.from_numpy(np.concatenate(ys))
        loss = fit(net, optim, x_all, y_all, hp, rng)
        o = np.concatenate(outcomes)
        row = {
            "iteration": it,
            "beta": beta,
            "states": len(y_all),
            "rollout_success": float((o == SUCCESS).mean()),
            "rollout_crash": float((o == CRASH).mean()),
            "loss": loss,
            "rollout_cpu_s": round(t_fit - t_roll, 2),
            "fit_cpu_s": round(time.process_time() - t_fit, 2),
        }
        log.append(row)
        if progress:
            print(" ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()), flush=True)
    t_sel = time.process_time()
    offset, selection = select_offset(net, suites, hp)
    stats = {
        "iterations": hp.steps,
        "states": int(sum(len(y) for y in ys)),
        "overtake_label_share": float(np.mean(np.concatenate(ys) == OVERTAKE)),
        "overtake_logit_offset": offset,
        "threshold_selection": selection,
        "selection_cpu_s": round(time.process_time() - t_sel, 1),
        "cpu_time_s": round(time.process_time() - cpu0, 1),
        "log": log,
    }
    if out is not None:
        with open(out / "log.csv", "w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(log[0]))
            writer.writeheader()
            writer.writerows(log)
    return net, offset, {**stats, "wall_time_s": time.perf_counter() - t0}


def with_offset(net: QNetwork, offset: float) -> QNetwork:
    """A copy of ``net`` whose OVERTAKE logit is shifted by ``offset`` (the threshold, in the weights)."""
    shipped = copy.deepcopy(net)
    with torch.no_grad():
        shipped.head.bias[OVERTAKE] += offset
    return shipped


def train(
    suites: list[Any],
    *,
    member: str = "dagger",
    suite_name: str | None = None,
    steps: int | None = None,
    seed: int | None = None,
    out: str | Path | None = None,
    resume: str | Path | None = None,
    hyperparams: str | Path | None = None,
    overrides: dict[str, Any] | None = None,
    progress: bool = True,
) -> Trained:
    """Train ``dagger`` on the loaded training ``suites`` (``suite_name``: their spec, for the card);
    ``steps`` (DAgger iterations) and ``seed`` override the file (default ``zoo/hyperparams/dagger.toml``)."""
    if member != "dagger":
        raise TrainError(f"train/dagger.py trains dagger, not {member!r}")
    if resume:
        raise TrainError("dagger keeps no checkpoint (it trains in minutes): run it again without --resume")
    out_dir = check_writable_dir(out) if out else None
    hp, hp_file = load_hyperparams(DAggerHyperparams, hyperparams or hyperparams_file(member), overrides)
    hp = dataclasses.replace(
        hp, seed=hp.seed if seed is None else int(seed), steps=hp.steps if steps is None else int(steps)
    )
    net, offset, stats = run(suites, hp, out_dir, progress)
    wall = float(stats.pop("wall_time_s"))
    source = suite_source(suites, suite_name)
    card = model_card(
        member,
        algorithm=ALGORITHM,
        architecture={"kind": "classifier"},
        hp=hp,
        hp_file=hp_file,
        action_repeat=hp.action_repeat,
        action_mask=hp.action_mask,
        source=source,
        steps=hp.steps,
        steps_unit=STEPS_UNIT,
        seed=hp.seed,
        wall_time_s=wall,
        training=stats,
        reproduce=reproduce(member, source, hp.steps, hp.seed),
    )
    if hp.frame_stack > 1:  # the member reads its last frame_stack decisions (StackedMLPDecider)
        card["frame_stack"] = hp.frame_stack
    return finish(card, module=with_offset(net, offset), out=out_dir)
