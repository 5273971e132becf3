"""DQN and Double DQN deciders: an MLP Q-network over the observation, argmax over the three modes.

The paper's method (Malayjerdi et al.): a Q-network picks follow / overtake / abort; training is in
:mod:`overtakezoo.zoo.train_dqn`. Two choices of ours, both recorded in each model card:

- **Action repeat** (``action_repeat`` = k): a decision is held for k core steps (k * dt seconds),
  in training and in evaluation. The decider only declares k (from its model card); the hold itself
  is applied by whoever steps the core (``overtakezoo.envs.hold``: the benchmark runner, the
  trainer), combined with the configuration's ``decision_interval``.
- **Float64 inference**: float32 Q-values move by ~1e-6 with the batch's composition, enough to
  flip a near-tie argmax; in float64 a result does not depend on how rows happen to be batched.
- **Action mask** (a mode-transition rule, the same in training and evaluation): ABORT is only
  offered while the current mode is OVERTAKE or ABORT (from follow there is nothing to abort), and
  FOLLOW only while the mode is FOLLOW or the ego is back inside its own lane. Out in the opposite
  lane the way back is ABORT, which merges only once the lane beside the ego is clear; FOLLOW there
  forces the centre rollout at once and cuts into the lead (what the unmasked network learned to do
  in its few crashes). Version 3 also carries an abort through: while aborting outside its lane
  the ego may not resume the overtake (abort / overtake flip-flops were the next crash cause).

Pretrained weights live in ``zoo/pretrained/<name>.pt`` with a model card ``<name>.json`` that
holds, among the provenance, the sha256 of the weights; loading refuses a file whose hash differs
(truncated, modified) with :class:`WeightsError`. Loading reads local files only.
"""

from __future__ import annotations

import copy
import io
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from overtakezoo.envs import ABORT, FOLLOW, OVERTAKE, EnvConfig, observation_layout, observation_size

from .base import Decider, register
from .common import WeightsError, read_card, read_verified  # noqa: F401 (WeightsError is re-exported)
from .features import FEATURES_VERSION, speed_relative

PRETRAINED = Path(__file__).resolve().parent / "pretrained"
NUM_MODES = 3


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


# The ego is inside its own lane while |y| / lane width is below this (car 1.82 m in a 3.5 m lane).
IN_LANE = 0.25
MASK_VERSION = 3


def action_mask(obs: np.ndarray | torch.Tensor, config: EnvConfig, version: int = MASK_VERSION
                ) -> np.ndarray | torch.Tensor:
    """(N, 3) bool: which modes a row may choose. ABORT only while overtaking or aborting; FOLLOW
    only from FOLLOW or with the ego inside its own lane; (version >= 3) OVERTAKE not while an
    abort is still bringing the ego back to its lane."""
    layout = observation_layout(config)
    mode = obs[:, layout["mode"]]
    in_follow, in_abort = mode[:, FOLLOW] > 0.5, mode[:, ABORT] > 0.5
    lateral = obs[:, layout["ego"]][:, 2]  # y / lane width
    in_lane = (lateral.abs() if isinstance(obs, torch.Tensor) else np.abs(lateral)) < IN_LANE
    if isinstance(obs, torch.Tensor):
        mask = torch.ones(obs.shape[0], NUM_MODES, dtype=torch.bool, device=obs.device)
    else:
        mask = np.ones((obs.shape[0], NUM_MODES), bool)
    mask[:, ABORT] = ~in_follow
    mask[:, FOLLOW] = in_follow | in_lane
    if version >= 3:
        mask[:, OVERTAKE] = ~in_abort | in_lane
    return mask


def masked_argmax(q: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    if mask is not None:
        q = q.masked_fill(~mask, float("-inf"))
    return q.argmax(dim=1)


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


def load_weights(weights: str | Path, card: dict[str, Any]) -> QNetwork:
    """Build the network described by ``card`` and load ``weights`` after checking its sha256."""
    weights = Path(weights)
    data = read_verified(weights, card, card.get("name", "dqn"))
    arch = card["architecture"]
    net = QNetwork(arch["obs_dim"], arch["hidden"], arch["dueling"])
    try:
        state = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
        net.load_state_dict(state)
    except Exception as exc:  # a hash-matching but unreadable file: say so in one line
        raise WeightsError(f"weights {weights.name}: cannot load ({type(exc).__name__}: {exc})") from None
    net.eval()
    return net


class DQNDecider(Decider):
    """Q-network decider: argmax Q over the allowed modes (each decision held ``action_repeat`` core
    steps by the runner)."""

    privileged = False

    def __init__(self, net: QNetwork, name: str = "dqn", config: EnvConfig | None = None,
                 action_repeat: int = 1, use_mask: bool = True, card: dict[str, Any] | None = None) -> None:
        super().__init__(config)
        if net.obs_dim != observation_size(self.config):
            raise WeightsError(f"{name}: network expects {net.obs_dim} observation features, the configuration "
                               f"gives {observation_size(self.config)} (different planner/observation settings)")
        self.net, self.name = net.eval(), name
        self._infer = copy.deepcopy(net).double().eval()
        self.action_repeat, self.use_mask = int(action_repeat), use_mask
        self.model_card = card or {}
        self.mask_version = int(self.model_card.get("action_mask_version", MASK_VERSION))
        self.version = str(self.model_card.get("version", "1"))
        self.weights_sha256 = self.model_card.get("weights_sha256")
        features = self.model_card.get("features")
        if features not in (None, FEATURES_VERSION):
            raise WeightsError(f"{name}: unknown input features {features!r} (this version has {FEATURES_VERSION!r})")
        self.features = features  # None: the raw observation (weights trained before the features existed)

    def _input(self, obs: np.ndarray) -> torch.Tensor:
        x = np.asarray(obs, np.float64)
        return torch.as_tensor(speed_relative(x, self.config) if self.features else x, dtype=torch.float64)

    def q_values(self, obs: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return self._infer(self._input(obs)).numpy()

    def act_batch(self, obs: np.ndarray) -> np.ndarray:
        """Argmax Q over the allowed modes (stateless: the hold is the runner's)."""
        with torch.no_grad():
            t = self._input(obs)
            mask = action_mask(t, self.config, self.mask_version) if self.use_mask else None
            return masked_argmax(self._infer(t), mask).numpy().astype(np.int64)

    def card(self) -> str:
        c = self.model_card
        if not c:
            return f"{self.name}: an untrained Q-network."
        res = c.get("results", {}).get("table1") or {}
        hp = c.get("hyperparameters", {})
        lines = [f"{self.name} ({c.get('algorithm', '?')}): MLP {c['architecture']['hidden']}"
                 f"{' dueling' if c['architecture'].get('dueling') else ''} Q-network over the "
                 f"{c['architecture']['obs_dim']}-feature observation, decision held "
                 f"{c.get('action_repeat', 1)} steps; mode-transition mask v{self.mask_version} (abort only from "
                 f"overtake, follow only from follow or in lane"
                 f"{', aborts carried through' if self.mask_version >= 3 else ''}).",
                 f"  trained on {c.get('train_suite', '?')} (sha256 {str(c.get('train_suite_hash') or '')[:12]}), "
                 f"{c.get('steps', '?')} transitions, seed {c.get('seed', '?')}, {c.get('wall_time_s', 0):.0f} s wall "
                 f"({hp.get('file', '?')})."]
        if res:
            lines.append(f"  table1: success {100 * res['success_rate']:.1f} % "
                         f"[{100 * res['success_ci'][0]:.1f}, {100 * res['success_ci'][1]:.1f}], crash "
                         f"{100 * res['crash_rate']:.1f} % [{100 * res['crash_ci'][0]:.1f}, "
                         f"{100 * res['crash_ci'][1]:.1f}] ({res['success']} successes, {res['crash']} crashes "
                         f"of {res['count']}).")
        lines.append(f"  weights sha256 {str(self.weights_sha256)[:16]}...; reproduce: {c.get('reproduce', '?')}")
        if c.get("selection_note"):
            lines.append(f"  {c['selection_note']}")
        return "\n".join(lines)


def from_card(name: str, card: dict[str, Any], weights: str | Path, config: EnvConfig | None = None) -> DQNDecider:
    net = load_weights(weights, card)
    return DQNDecider(net, name=name, config=config, action_repeat=card.get("action_repeat", 1),
                      use_mask=card.get("action_mask", True), card=card)


def load_pretrained(name: str, config: EnvConfig | None = None, directory: str | Path | None = None) -> DQNDecider:
    """The committed ``<name>.pt`` + ``<name>.json`` from ``zoo/pretrained`` (or ``directory``)."""
    directory = Path(directory) if directory else PRETRAINED
    card = read_card(directory / f"{name}.json", name)
    return from_card(name, card, directory / f"{name}.pt", config)


register("dqn", lambda config=None, **kw: load_pretrained("dqn", config, **kw))
register("double-dqn", lambda config=None, **kw: load_pretrained("double-dqn", config, **kw))
