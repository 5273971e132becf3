"""Behaviour cloning (the ``bc`` member): an MLP classifier of a recorded dataset's modes.

It acts by the argmax of its logits among the modes the action mask allows (the most frequent mode
of the data in that state, epsilon noise averaged out), every step (``action_repeat`` = 1).
Reads top to bottom: the hyperparameters (``zoo/hyperparams/bc.toml``), the network, the loop
(minibatches of per-step transitions, cross-entropy against the recorded mode, Adam), then the
outputs (numpy weights + model card, :mod:`.contract`). The data are per-step transitions (the
:mod:`.offline` docstring says why); the features are the speed-relative ones the other learned
members use. :func:`train` takes the dataset loaded and returns the :class:`~.contract.Trained`
member; into ``out`` it writes ``bc.npz`` and ``bc.json`` (no torch file, no log, no checkpoint).

    overtakezoo train bc --dataset overtakezoo/table1/rule-fsm-v0 --out runs/bc
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from overtakezoo.zoo.train.contract import Trained, TrainError
from overtakezoo.zoo.train.offline import Transitions, progress_bar, train_offline
from overtakezoo.zoo.train.qlearning import QNetwork  # the one torch MLP of the zoo (Linear / ReLU layers)
from overtakezoo.zoo.train.typed import param

LEARNS_FROM = "dataset"  # what train() takes: loaded training suites, or a loaded dataset
ALGORITHM = "behaviour cloning (cross-entropy on the recorded modes)"


@dataclass(frozen=True)
class BCHyperparams:
    seed: int = param(0, 0, 2**31 - 1)
    steps: int = param(20000, 1, 10**8)  # gradient steps
    batch_size: int = param(512, 1, 1 << 20)
    lr: float = param(1e-3, 1e-7, 1.0)
    weight_decay: float = param(0.0, 0.0, 1.0)
    hidden: tuple[int, ...] = param((128, 128), 1, 4096)
    holdout: float = param(0.1, 0.0, 0.5)  # share of episodes kept out of training, for the accuracy report
    action_mask: bool = param(True)  # act among the modes dqn's mode-transition mask allows
    timeout_terminal: bool = param(True)  # unused by bc (no bootstrapping); kept for one data recipe
    threads: int = param(1, 1, 256)


def split(data: Transitions, holdout: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Row indices of the training and held-out transitions, split by whole episodes."""
    episodes = np.unique(data.episode)
    rng = np.random.default_rng(seed)
    held = rng.permutation(episodes)[: int(round(holdout * len(episodes)))]
    out = np.isin(data.episode, held)
    return np.flatnonzero(~out), np.flatnonzero(out)


def accuracy(net: nn.Module, x: np.ndarray, y: np.ndarray) -> float | None:
    if len(y) == 0:
        return None
    with torch.no_grad():
        return float((net(torch.from_numpy(x)).argmax(1).numpy() == y).mean())


def cross_entropy_step(
    net: nn.Module,
    optim: torch.optim.Optimizer,
    x: torch.Tensor,
    y: torch.Tensor,
    rng: np.random.Generator,
    batch_size: int,
) -> torch.Tensor:
    """One Adam step of cross-entropy on a minibatch drawn (with replacement) by ``rng``: the
    supervised update of bc and of dagger's classifier; returns the minibatch loss."""
    idx = torch.from_numpy(rng.integers(0, len(y), batch_size))
    loss = nn.functional.cross_entropy(net(x[idx]), y[idx])
    optim.zero_grad(set_to_none=True)
    loss.backward()
    optim.step()
    return loss


def fit(data: Transitions, hp: BCHyperparams, progress: bool = True) -> tuple[QNetwork, dict[str, Any]]:
    """Train the classifier; returns it with training statistics (accuracies, wall time)."""
    torch.manual_seed(hp.seed)
    torch.set_num_threads(hp.threads)
    rng = np.random.default_rng(hp.seed)
    train_rows, held_rows = split(data, hp.holdout, hp.seed)
    x, y = torch.from_numpy(data.obs[train_rows]), torch.from_numpy(data.action[train_rows])
    net = QNetwork(data.obs.shape[1], hp.hidden, dueling=False)  # logits over the modes
    optim = torch.optim.Adam(net.parameters(), lr=hp.lr, weight_decay=hp.weight_decay)
    t0, cpu0 = time.perf_counter(), time.process_time()
    bar = progress_bar(hp.steps, "bc", progress)
    for step in range(hp.steps):
        loss = cross_entropy_step(net, optim, x, y, rng, hp.batch_size)
        if bar is not None:
            bar.update(1)
            if step % 500 == 0:
                bar.set_postfix(loss=f"{float(loss):.4f}", refresh=False)
    if bar is not None:
        bar.close()
    net.eval()
    stats = {
        "train_accuracy": accuracy(net, data.obs[train_rows], data.action[train_rows]),
        "heldout_accuracy": accuracy(net, data.obs[held_rows], data.action[held_rows]),
        "heldout_episodes": int(len(np.unique(data.episode[held_rows]))),
        "gradient_steps": hp.steps,
        "transitions": len(data),
        "cpu_time_s": round(time.process_time() - cpu0, 1),
        "wall_time_s": time.perf_counter() - t0,
    }
    return net, stats


def train(
    dataset: Any,
    about: dict[str, Any],
    *,
    member: str = "bc",
    steps: int | None = None,
    seed: int | None = None,
    out: str | Path | None = None,
    resume: str | Path | None = None,
    hyperparams: str | Path | None = None,
    overrides: dict[str, Any] | None = None,
    progress: bool = True,
) -> Trained:
    """Train bc on the loaded Minari ``dataset`` (``about``: its registry name and content hash,
    :func:`.offline.identity`); ``out`` receives ``bc.npz`` + ``bc.json``. ``seed`` and ``steps``
    (gradient steps) override the hyperparameter file (default ``zoo/hyperparams/bc.toml``)."""
    if member != "bc":
        raise TrainError(f"train/bc.py trains bc, not {member!r}")
    return train_offline(
        "bc",
        BCHyperparams,
        fit,
        ALGORITHM,
        "classifier",
        dataset,
        about,
        steps=steps,
        seed=seed,
        out=out,
        resume=resume,
        hyperparams=hyperparams,
        overrides=overrides,
        progress=progress,
    )
