"""PPO decider: a policy trained with rsl-rl-lib's ``OnPolicyRunner``; acts by the argmax of its logits.

Training is in :mod:`overtakezoo.zoo.train_ppo` (torch, rsl-rl). Acting is numpy only
(:mod:`overtakezoo.zoo.learned`, shared with dqn): ``zoo/pretrained/ppo.npz`` holds the actor's
layers, the model card ``ppo.json`` beside it the architecture, the provenance and the sha256 of
the weights, checked before loading. Loading is local only.
"""

from __future__ import annotations

from pathlib import Path

from overtakezoo.envs import EnvConfig

from .base import register
from .common import WeightsError  # noqa: F401 (re-exported)
from .learned import PRETRAINED, MLPDecider, from_card, load_pretrained as _load  # noqa: F401

PPODecider = MLPDecider  # the learned members share one decider


def load_pretrained(config: EnvConfig | None = None, directory: str | Path | None = None) -> MLPDecider:
    """``ppo.npz`` + ``ppo.json`` from ``zoo/pretrained`` (or ``directory``), sha256 checked."""
    return _load("ppo", config, directory)


register("ppo", lambda config=None, **kw: load_pretrained(config, **kw))
