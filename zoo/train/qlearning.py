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

    def __init__(self, obs_dim: int, hidden: list[int] | tuple[int, ...] = (128, 128), dueling: bool = True,
                 num_actions: int = NUM_MODES) -> None:
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

    def sample(self, batch: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
        idx = rng.integers(0, self.size, batch)
        return {"obs": self.obs[idx], "action": self.action[idx], "reward": self.reward[idx],
                "next_obs": self.next_obs[idx], "done": self.done[idx]}

    def state(self) -> dict[str, Any]:
        n = self.size
        return {"size": n, "ptr": self.ptr, "obs": self.obs[:n].copy(), "next_obs": self.next_obs[:n].copy(),
                "action": self.action[:n].copy(), "reward": self.reward[:n].copy(), "done": self.done[:n].copy()}

    def load(self, state: dict[str, Any]) -> None:
        n = min(int(state["size"]), self.capacity)
        for key in ("obs", "next_obs", "action", "reward", "done"):
            getattr(self, key)[:n] = np.asarray(state[key])[:n]
        self.size, self.ptr = n, int(state["ptr"]) % self.capacity


# ----------------------------------------------------------------------------- acting
def masked_argmax(q: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    """Row-wise argmax of ``q`` over the modes ``mask`` allows."""
    if mask is not None:
        q = q.masked_fill(~mask, float("-inf"))
    return q.argmax(dim=1)


# ----------------------------------------------------------------------------- TD target
def td_targets(online: nn.Module, target: nn.Module, reward: torch.Tensor, next_obs: torch.Tensor,
               done: torch.Tensor, gamma: float, double: bool, next_mask: torch.Tensor | None = None) -> torch.Tensor:
    """TD targets. DQN: ``r + gamma * max_a Q_target(s', a)``; Double DQN (van Hasselt et al. 2016):
    ``r + gamma * Q_target(s', argmax_a Q_online(s', a))`` -- the online net picks, the target net
    evaluates, which removes the max operator's overestimation bias. ``done`` rows do not bootstrap."""
    with torch.no_grad():
        q_next = target(next_obs)
        if double:
            best = masked_argmax(online(next_obs), next_mask)
        else:
            best = masked_argmax(q_next, next_mask)
        boot = q_next.gather(1, best[:, None])[:, 0]
        return reward + gamma * (1.0 - done.float()) * boot
