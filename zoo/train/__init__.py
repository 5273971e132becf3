"""How the learned members are trained (torch; acting needs none of it, :mod:`..members`).

- ``contract.py``: what every trainer reads and writes: hyperparameters, the model card and its
  JSON Schema (``card.schema.json``), the outputs;
- ``dqn.py`` (dqn, double-dqn, ps-dqn) with ``qlearning.py`` (the network, the replay buffer, the
  TD target); ``ppo.py`` (ppo, through rsl-rl, with ``categorical.py``, its action distribution);
  ``bc.py`` and ``cql.py`` (offline, from a dataset's transitions, ``offline.py``); ``dagger.py``
  (the privileged oracle distilled into an observation-only classifier, DAgger);
- ``export.py``: torch weights -> the numpy ``.npz`` the zoo loads; ``typed.py``: the typed
  dataclasses the hyperparameter files are read into.

Each trainer's ``train(...)`` takes what it learns from already loaded (``LEARNS_FROM``: training
suites or a dataset) and returns a :class:`.contract.Trained`; ``overtakezoo.benchmark.run.training``
(the ``overtakezoo train`` command) loads those, calls it and evaluates the result.
"""
