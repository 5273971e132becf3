"""The pieces of deep Q-learning, in torch: the Q-network, the replay buffer, acting on Q-values,
the TD target. :mod:`.dqn` assembles them into its training loop; :mod:`.cql` reuses the network
and its double-DQN target, :mod:`.bc` the network as a classifier (``dueling=False``: an MLP of
``nn.Linear`` / ReLU layers, the layout :func:`.export.dqn_net` reads).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import nn

from overtakezoo.zoo.members.learned import NUM_MODES
from overtakezoo.zoo.members.mlp import NumpyMLP
from overtakezoo.zoo.train.export import dqn_net


# ----------------------------------------------------------------------------- Q-network
class QNetwork(nn.Module):
    """MLP Q-network; with ``dueling`` the head splits into value + mean-centred advantages."""

    def __init__(
        self,
        obs_dim: int,
        hidden: list[int] | tuple[int, ...] = (128, 128),
        dueling: bool = True,
        num_actions: int = NUM_MODES,
    ) -> None:
        super().__init__()
        self.obs_dim, self.hidden, self.dueling = obs_dim, list(hidden), dueling
        layers: list[nn.Module] = []
        width = obs_dim
        for h in hidden:
            layers += [nn.Linear(width, h), nn.ReLU()]
            width = h
        self.body = nn.Sequential(*layers)
        self.head = nn.Linear(width, num_actions + (1 if dueling else 0))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        out = self.head(self.body(obs))
        if not self.dueling:
            return out
        value, adv = out[:, :1], out[:, 1:]
        return value + adv - adv.mean(dim=1, keepdim=True)

    def to_numpy(self) -> NumpyMLP:
        """The same network for numpy inference (float64), as exported."""
        return dqn_net(self.state_dict(), self.dueling)


# ----------------------------------------------------------------------------- replay buffer
class ReplayBuffer:
    """Fixed-size ring of transitions as numpy arrays; inserts and samples are vectorized. ``steps``
    is how many decisions a transition spans (1; more for n-step returns, :class:`NStepReturns`)."""

    KEYS = ("obs", "next_obs", "action", "reward", "done", "steps")

    def __init__(self, capacity: int, obs_dim: int) -> None:
        self.capacity, self.size, self.ptr = int(capacity), 0, 0
        self.obs = np.zeros((capacity, obs_dim), np.float32)
        self.next_obs = np.zeros((capacity, obs_dim), np.float32)
        self.action = np.zeros(capacity, np.int64)
        self.reward = np.zeros(capacity, np.float32)
        self.done = np.zeros(capacity, np.float32)
        self.steps = np.ones(capacity, np.float32)

    def add(
        self,
        obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        next_obs: np.ndarray,
        done: np.ndarray,
        steps: np.ndarray | None = None,
    ) -> None:
        n = len(action)
        idx = (self.ptr + np.arange(n)) % self.capacity
        self.obs[idx], self.action[idx], self.reward[idx] = obs, action, reward
        self.next_obs[idx], self.done[idx] = next_obs, done
        self.steps[idx] = 1.0 if steps is None else steps
        self.ptr = int((self.ptr + n) % self.capacity)
        self.size = int(min(self.size + n, self.capacity))

    def sample(self, batch: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
        idx = rng.integers(0, self.size, batch)
        return {key: getattr(self, key)[idx] for key in self.KEYS}

    def state(self) -> dict[str, Any]:
        n = self.size
        return {"size": n, "ptr": self.ptr, **{key: getattr(self, key)[:n].copy() for key in self.KEYS}}

    def load(self, state: dict[str, Any]) -> None:
        n = min(int(state["size"]), self.capacity)
        for key in self.KEYS:
            if key in state:  # checkpoints from before n-step returns have no "steps": all 1
                getattr(self, key)[:n] = np.asarray(state[key])[:n]
        self.size, self.ptr = n, int(state["ptr"]) % self.capacity


class NStepReturns:
    """n-step transitions (Sutton & Barto 2018, ch. 7; one of Rainbow's parts, Hessel et al. 2018),
    built as the decisions of many parallel rows arrive: ``(s_t, a_t, r_t + g r_t+1 + ... +
    g^(k-1) r_t+k-1, s_t+k, done, k)`` with ``k = n``, or fewer where the episode ended first.
    Each row holds its last ``n`` unfinished transitions in slot ``decision % n``; an episode's end
    flushes its row. The TD target then discounts by ``g^k`` (:func:`td_targets`). Vectorized over
    rows and slots: the loop is the trainer's, one :meth:`push` per decision."""

    def __init__(self, n: int, gamma: float, rows: int, obs_dim: int) -> None:
        self.n, self.gamma, self.t = int(n), float(gamma), 0
        self.obs = np.zeros((n, rows, obs_dim), np.float32)
        self.action = np.zeros((n, rows), np.int64)
        self.ret = np.zeros((n, rows), np.float64)
        self.age = np.zeros((n, rows), np.int64)  # decisions a pending transition spans; 0: slot free

    def push(
        self,
        obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        next_obs: np.ndarray,
        done: np.ndarray,
        finished: np.ndarray,
        valid: np.ndarray | None = None,
    ) -> dict[str, np.ndarray]:
        """One decision of every row (``valid``: the rows that made one; a waiting AV did not).
        ``next_obs`` / ``done`` are the decision's (the final observation where ``finished``: the
        episode ended, by its task or a time limit). Returns the transitions complete now."""
        valid = np.ones(len(action), bool) if valid is None else np.asarray(valid, bool)
        live = (self.age > 0) & valid[None]
        self.ret += np.where(live, self.gamma**self.age * reward[None], 0.0)
        self.age += live
        slot = self.t % self.n
        if (self.age[slot] > 0)[valid].any():  # cannot happen: an entry n decisions old left last push
            raise AssertionError("n-step slot still pending")
        self.obs[slot, valid], self.action[slot, valid] = obs[valid], action[valid]
        self.ret[slot, valid], self.age[slot, valid] = reward[valid], 1
        self.t += 1
        emit = (self.age > 0) & valid[None] & ((self.age >= self.n) | np.asarray(finished, bool)[None])
        k, row = np.nonzero(emit)
        out: dict[str, np.ndarray] = {
            "obs": self.obs[k, row],
            "action": self.action[k, row],
            "reward": self.ret[k, row].astype(np.float32),
            "next_obs": next_obs[row],
            "done": np.asarray(done, np.float32)[row],
            "steps": self.age[k, row].astype(np.float32),
        }
        self.age[k, row] = 0
        return out


# ----------------------------------------------------------------------------- acting
def masked_argmax(q: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    """Row-wise argmax of ``q`` over the modes ``mask`` allows."""
    if mask is not None:
        q = q.masked_fill(~mask, float("-inf"))
    return q.argmax(dim=1)


# ----------------------------------------------------------------------------- TD target
def td_targets(
    online: nn.Module,
    target: nn.Module,
    reward: torch.Tensor,
    next_obs: torch.Tensor,
    done: torch.Tensor,
    gamma: float | torch.Tensor,
    double: bool,
    next_mask: torch.Tensor | None = None,
) -> torch.Tensor:
    """TD targets. DQN: ``r + gamma * max_a Q_target(s', a)``; Double DQN (van Hasselt et al. 2016):
    ``r + gamma * Q_target(s', argmax_a Q_online(s', a))`` -- the online net picks, the target net
    evaluates, which removes the max operator's overestimation bias. ``done`` rows do not bootstrap.
    ``gamma`` may be a tensor, one discount per row (``g^k`` for a k-step transition)."""
    with torch.no_grad():
        q_next = target(next_obs)
        if double:
            best = masked_argmax(online(next_obs), next_mask)
        else:
            best = masked_argmax(q_next, next_mask)
        boot = q_next.gather(1, best[:, None])[:, 0]
        return reward + gamma * (1.0 - done.float()) * boot
