"""Discrete conservative Q-learning (the ``cql`` decider) from a recorded dataset.

Kumar et al. 2020, "Conservative Q-Learning for Offline Reinforcement Learning", the variant for
discrete actions (their Atari experiments; d3rlpy's ``DiscreteCQL``): a double-DQN TD loss plus

    alpha * mean( logsumexp_a Q(s, a) - Q(s, a_data) )

which pushes down the Q-values of every mode in proportion to their softmax weight and up the one
the dataset took, so a mode the data rarely or never chose in a state is not over-estimated (the
failure of plain off-policy Q-learning on a fixed dataset). The TD target is double DQN's (van
Hasselt et al. 2016): the online net picks the next mode among those the action mask allows, the
target net (a copy every ``target_update`` gradient steps) evaluates it; ``done`` rows do not
bootstrap. Huber loss, Adam, gradient-norm clipping.

It acts by the argmax of its Q-values among the modes the action mask allows, every step
(``action_repeat`` = 1). Reads top to bottom: the hyperparameters (``zoo/hyperparams/cql.toml``),
the loss, the loop, the outputs (the card shared with bc in :mod:`.offline`, the files of
:mod:`.contract`: ``cql.npz`` + ``cql.json``). Transitions are per simulator step (0.1 s), so
``gamma`` is per step (see :mod:`.offline`'s docstring for why). :func:`train` takes the dataset
loaded and returns the :class:`~.contract.Trained` member.

    overtakezoo train cql --dataset overtakezoo/table1/rule-fsm-v0 --out runs/cql
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from overtakezoo.zoo.members.learned import action_mask
from overtakezoo.zoo.train.contract import Trained, TrainError
from overtakezoo.zoo.train.offline import Transitions, progress_bar, train_offline
from overtakezoo.zoo.train.qlearning import QNetwork, td_targets
from overtakezoo.zoo.train.typed import param

LEARNS_FROM = "dataset"  # what train() takes: loaded training suites, or a loaded dataset
ALGORITHM = "discrete CQL (Kumar et al. 2020) on double DQN"


@dataclass(frozen=True)
class CQLHyperparams:
    seed: int = param(0, 0, 2**31 - 1)
    steps: int = param(100000, 1, 10**8)  # gradient steps
    batch_size: int = param(256, 1, 1 << 20)
    lr: float = param(3e-4, 1e-7, 1.0)
    gamma: float = param(0.995, 0.0, 1.0)  # per 0.1 s step
    alpha: float = param(0.1, 0.0, 1e4)  # weight of the conservative term (cql.toml says why 0.1)
    target_update: int = param(1000, 1, 10**8)  # gradient steps between hard target copies
    huber_delta: float = param(1.0, 1e-6, 1e6)
    grad_clip: float = param(10.0, 1e-6, 1e6)
    hidden: tuple[int, ...] = param((128, 128), 1, 4096)
    action_mask: bool = param(True)  # the next mode (TD target) and the acting mode among the allowed ones
    timeout_terminal: bool = param(True)  # a timeout ends the episode (the observation has no clock)
    threads: int = param(1, 1, 256)


def cql_loss(
    net: nn.Module, target: nn.Module, b: dict[str, torch.Tensor], hp: CQLHyperparams
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(total, TD, conservative) losses on a minibatch ``b``."""
    q = net(b["obs"])
    q_data = q.gather(1, b["action"][:, None])[:, 0]
    y = td_targets(net, target, b["reward"], b["next_obs"], b["done"], hp.gamma, True, b.get("next_mask"))
    td = nn.functional.huber_loss(q_data, y, delta=hp.huber_delta)
    conservative = (torch.logsumexp(q, dim=1) - q_data).mean()
    return td + hp.alpha * conservative, td, conservative


def fit(data: Transitions, hp: CQLHyperparams, progress: bool = True) -> tuple[QNetwork, dict[str, Any]]:
    """Train the Q-network on every transition of ``data``; returns it with training statistics."""
    torch.manual_seed(hp.seed)
    torch.set_num_threads(hp.threads)
    rng = np.random.default_rng(hp.seed)
    tensors = {
        "obs": torch.from_numpy(data.obs),
        "action": torch.from_numpy(data.action),
        "reward": torch.from_numpy(data.reward),
        "next_obs": torch.from_numpy(data.next_obs),
        "done": torch.from_numpy(data.done),
    }
    if hp.action_mask:  # the mask reads the observation layout, which the features keep
        tensors["next_mask"] = torch.from_numpy(action_mask(data.next_obs, data.config))
    net = QNetwork(data.obs.shape[1], hp.hidden, dueling=False)
    target = copy.deepcopy(net)
    optim = torch.optim.Adam(net.parameters(), lr=hp.lr)
    t0, cpu0 = time.perf_counter(), time.process_time()
    bar = progress_bar(hp.steps, "cql", progress)
    td = conservative = torch.zeros(())
    for step in range(1, hp.steps + 1):
        idx = torch.from_numpy(rng.integers(0, len(data), hp.batch_size))
        loss, td, conservative = cql_loss(net, target, {k: v[idx] for k, v in tensors.items()}, hp)
        optim.zero_grad(set_to_none=True)
        loss.backward()
        nn.utils.clip_grad_norm_(net.parameters(), hp.grad_clip)
        optim.step()
        if step % hp.target_update == 0:
            target.load_state_dict(net.state_dict())
        if bar is not None:
            bar.update(1)
            if step % 500 == 0:
                bar.set_postfix(td=f"{float(td):.4f}", cql=f"{float(conservative):.3f}", refresh=False)
    if bar is not None:
        bar.close()
    net.eval()
    with torch.no_grad():
        q = net(tensors["obs"][:: max(1, len(data) // 20000)])
    stats = {
        "final_td_loss": float(td.detach()),
        "final_conservative_loss": float(conservative.detach()),
        "mean_q": float(q.mean()),
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
    member: str = "cql",
    steps: int | None = None,
    seed: int | None = None,
    out: str | Path | None = None,
    resume: str | Path | None = None,
    hyperparams: str | Path | None = None,
    overrides: dict[str, Any] | None = None,
    progress: bool = True,
) -> Trained:
    """Train cql on the loaded Minari ``dataset`` (``about``: its registry name and content hash,
    :func:`.offline.identity`); ``out`` receives ``cql.npz`` + ``cql.json``. ``seed`` and ``steps``
    (gradient steps) override the hyperparameter file (default ``zoo/hyperparams/cql.toml``)."""
    if member != "cql":
        raise TrainError(f"train/cql.py trains cql, not {member!r}")
    return train_offline(
        "cql",
        CQLHyperparams,
        fit,
        ALGORITHM,
        "q-network",
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
