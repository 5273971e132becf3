"""``bc`` and ``cql``: deciders trained offline from a recorded dataset, acting through numpy.

- ``bc``, behaviour cloning: an MLP classifier of the dataset's modes (cross-entropy); it acts by
  the argmax of its logits (the most frequent mode of the data in that state, epsilon noise
  averaged out).
- ``cql``, discrete conservative Q-learning (Kumar et al. 2020, "Conservative Q-Learning for
  Offline Reinforcement Learning", the discrete-action variant on a double DQN): it acts by the
  argmax of its Q-values.

Both are :class:`~overtakezoo.zoo.learned.MLPDecider` s, as dqn and ppo are: they see the
speed-relative features (:mod:`overtakezoo.zoo.features`), act every core step (``action_repeat``
= 1: the datasets hold one transition per step, see :mod:`overtakezoo.zoo.offline_data`) and choose
among the modes the action mask allows. Training is in :mod:`overtakezoo.zoo.train_bc` and
:mod:`overtakezoo.zoo.train_cql` (torch). Weights are ``zoo/pretrained/<name>.npz`` with the model
card ``<name>.json`` (dataset, hyperparameters, seed, results, reproduce command).
"""

from __future__ import annotations

from .base import register
from .learned import load_pretrained

register("bc", lambda config=None, **kw: load_pretrained("bc", config, **kw))
register("cql", lambda config=None, **kw: load_pretrained("cql", config, **kw))
