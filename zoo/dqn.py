"""DQN and Double DQN deciders: an MLP Q-network over the observation, argmax over the three modes.

The paper's method (Malayjerdi et al.): a Q-network picks follow / overtake / abort; training is in
:mod:`overtakezoo.zoo.train_dqn` (torch). Acting is numpy only (:mod:`overtakezoo.zoo.learned`,
shared with ppo). Three choices of ours, each recorded in the model card:

- **Action repeat** (``action_repeat`` = k): a decision is held for k core steps (k * dt seconds),
  in training and in evaluation. The decider only declares k (from its model card); the hold itself
  is applied by whoever steps the core (``overtakezoo.envs.hold``: the benchmark runner, the
  trainer), combined with the configuration's ``decision_interval``.
- **Float64 inference**, so that an argmax does not depend on how rows are batched.
- **Action mask** (:func:`~overtakezoo.zoo.learned.action_mask`): a mode-transition rule, the same
  in training and evaluation.

Pretrained weights live in ``zoo/pretrained/<name>.npz`` with a model card ``<name>.json`` that
holds, among the provenance, the sha256 of the weights; loading refuses a file whose hash differs
(truncated, modified) with :class:`WeightsError`. Loading reads local files only.
"""

from __future__ import annotations

from pathlib import Path

from overtakezoo.envs import EnvConfig

from .base import register
from .common import WeightsError  # noqa: F401 (re-exported)
from .learned import (IN_LANE, MASK_VERSION, NUM_MODES, PRETRAINED, MLPDecider, action_mask,  # noqa: F401
                      from_card, load_weights, masked_argmax)
from .learned import load_pretrained as _load

DQNDecider = MLPDecider  # the learned members share one decider


def load_pretrained(name: str, config: EnvConfig | None = None, directory: str | Path | None = None) -> MLPDecider:
    """The committed ``<name>.npz`` + ``<name>.json`` from ``zoo/pretrained`` (or ``directory``)."""
    return _load(name, config, directory)


register("dqn", lambda config=None, **kw: load_pretrained("dqn", config, **kw))
register("double-dqn", lambda config=None, **kw: load_pretrained("double-dqn", config, **kw))
# ps-dqn: DQN whose one Q-network drove every AV of multi-AV roads in training (parameter sharing).
register("ps-dqn", lambda config=None, **kw: load_pretrained("ps-dqn", config, **kw))
