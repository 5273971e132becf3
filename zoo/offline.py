"""``bc`` and ``cql``: deciders trained offline from a recorded dataset, acting through numpy.

- ``bc``, behaviour cloning: an MLP classifier of the dataset's modes (cross-entropy); it acts by
  the argmax of its logits (the most frequent mode of the data in that state, epsilon noise
  averaged out).
- ``cql``, discrete conservative Q-learning (Kumar et al. 2020, "Conservative Q-Learning for
  Offline Reinforcement Learning", the discrete-action variant on a double DQN): it acts by the
  argmax of its Q-values.

Both see the speed-relative features (:mod:`overtakezoo.zoo.features`), act every core step
(``action_repeat`` = 1: the datasets hold one transition per step, see
:mod:`overtakezoo.zoo.offline_data`) and choose among the modes the dqn action mask allows (a
mode-transition rule: abort only while overtaking, follow only from follow or inside the ego lane).
Training is in :mod:`overtakezoo.zoo.train_bc` and :mod:`overtakezoo.zoo.train_cql` (torch);
acting needs numpy only. Weights are ``zoo/pretrained/<name>.npz`` with the model card
``<name>.json`` (dataset, hyperparameters, seed, results, reproduce command); a file whose sha256
differs from the card's is refused with :class:`WeightsError`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from overtakezoo.envs import ABORT, FOLLOW, OVERTAKE, EnvConfig, observation_layout, observation_size

from .base import Decider, register
from .common import WeightsError, read_card, read_verified
from .features import FEATURES_VERSION, speed_relative
from .mlp import NumpyMLP, read_npz

PRETRAINED = Path(__file__).resolve().parent / "pretrained"
NUM_MODES = 3

# The action mask of zoo/dqn.py (``action_mask``, version 3), in numpy: zoo/dqn.py imports torch,
# which acting must not. Kept equal to it by tests/test_offline.py; import it from there once
# zoo/dqn.py is torch-free.
IN_LANE = 0.25
MASK_VERSION = 3


def action_mask(obs: np.ndarray, config: EnvConfig) -> np.ndarray:
    """(N, 3) bool: ABORT only while overtaking or aborting; FOLLOW only from FOLLOW or with the
    ego inside its own lane; OVERTAKE not while an abort is still bringing the ego back."""
    layout = observation_layout(config)
    mode = obs[:, layout["mode"]]
    in_follow, in_abort = mode[:, FOLLOW] > 0.5, mode[:, ABORT] > 0.5
    in_lane = np.abs(obs[:, layout["ego"]][:, 2]) < IN_LANE  # y / lane width
    mask = np.ones((obs.shape[0], NUM_MODES), bool)
    mask[:, ABORT] = ~in_follow
    mask[:, FOLLOW] = in_follow | in_lane
    mask[:, OVERTAKE] = ~in_abort | in_lane
    return mask


class OfflineDecider(Decider):
    """Argmax over the allowed modes of an MLP's outputs (logits for bc, Q-values for cql)."""

    def __init__(self, net: NumpyMLP, name: str, config: EnvConfig | None = None,
                 card: dict[str, Any] | None = None) -> None:
        super().__init__(config)
        self.net, self.name, self.model_card = net, name, card or {}
        if net.in_features != observation_size(self.config):
            raise WeightsError(f"{name}: network expects {net.in_features} features, the configuration gives "
                               f"{observation_size(self.config)} (different planner/observation settings)")
        features = self.model_card.get("features", FEATURES_VERSION)
        if features != FEATURES_VERSION:
            raise WeightsError(f"{name}: unknown input features {features!r} (this version has {FEATURES_VERSION!r})")
        self.use_mask = bool(self.model_card.get("action_mask", True))
        self.action_repeat = int(self.model_card.get("action_repeat", 1))
        self.version = str(self.model_card.get("version", "1"))
        self.weights_sha256 = self.model_card.get("weights_sha256")

    def scores(self, obs: np.ndarray) -> np.ndarray:
        """(N, 3) logits (bc) or Q-values (cql), float64."""
        return self.net(speed_relative(obs, self.config))

    def act_batch(self, obs: np.ndarray) -> np.ndarray:
        s = self.scores(obs)
        if self.use_mask:
            s = np.where(action_mask(np.asarray(obs, np.float64), self.config), s, -np.inf)
        return np.argmax(s, axis=1).astype(np.int64)

    def card(self) -> str:
        c = self.model_card
        if not c:
            return f"{self.name}: an offline-trained MLP."
        ds = c.get("dataset", {})
        lines = [f"{self.name} ({c.get('algorithm', '?')}): MLP {c['architecture']['hidden']} over the "
                 f"speed-relative features, acting every step; mode-transition mask v{c.get('action_mask_version')}.",
                 f"  trained offline on dataset {ds.get('name', '?')} ({ds.get('steps', '?')} steps, content sha256 "
                 f"{str(ds.get('content_sha256'))[:12]}), seed {c.get('seed', '?')}, {c.get('wall_time_s', 0):.0f} s."]
        res = c.get("results", {}).get("table1")
        if res:
            lines.append(f"  table1: success {100 * res['success_rate']:.1f} % [{100 * res['success_ci'][0]:.1f}, "
                         f"{100 * res['success_ci'][1]:.1f}], crash {100 * res['crash_rate']:.1f} % "
                         f"[{100 * res['crash_ci'][0]:.1f}, {100 * res['crash_ci'][1]:.1f}] of {res['count']}.")
        sel = c.get("seed_selection")
        if sel:
            lines.append(f"  seed {sel['shipped_seed']} of {len(sel['seeds'])}: {sel['rule']}.")
        lines.append(f"  weights sha256 {str(self.weights_sha256)[:16]}...; reproduce: {c.get('reproduce', '?')}")
        return "\n".join(lines)


def from_files(name: str, card: dict[str, Any], weights: str | Path, config: EnvConfig | None = None
               ) -> OfflineDecider:
    data = read_verified(weights, card, name)
    try:
        net = NumpyMLP.from_arrays(read_npz(data), card["architecture"].get("activation", "relu"))
    except Exception as exc:  # a hash-matching but unreadable file: say so in one line
        raise WeightsError(f"{name}: weights {Path(weights).name}: cannot load ({type(exc).__name__}: {exc})") from None
    return OfflineDecider(net, name, config, card)


def load_pretrained(name: str, config: EnvConfig | None = None, directory: str | Path | None = None
                    ) -> OfflineDecider:
    """The committed ``<name>.npz`` + ``<name>.json`` from ``zoo/pretrained`` (or ``directory``)."""
    directory = Path(directory) if directory else PRETRAINED
    card = read_card(directory / f"{name}.json", name)
    return from_files(name, card, directory / f"{name}.npz", config)


register("bc", lambda config=None, **kw: load_pretrained("bc", config, **kw))
register("cql", lambda config=None, **kw: load_pretrained("cql", config, **kw))
