"""The zoo's members at inference: numpy only, no torch (training is :mod:`overtakezoo.zoo.train`).

- ``rule_fsm.py`` (``rule-fsm``), ``fuzzy.py`` (``fuzzy``): hand-written rules;
- ``oracle.py`` (``oracle``): the privileged upper bound, which simulates the live core forward;
  ``joint_oracle.py`` (``joint-oracle``): its multi-AV form, planning every AV of a road together;
- ``learned.py``: every learned member (dqn, double-dqn, ps-dqn, ppo, bc, cql, dagger) is one
  :class:`~.learned.MLPDecider` over shipped weights (``zoo/pretrained/<name>.npz`` + model card),
  with ``features.py`` (its input) and ``mlp.py`` (the numpy network);
- ``shield.py``: the wrapper ``<name>+shield``, any member behind the RSS shield.

The registry (:mod:`overtakezoo.zoo.base`) lists the members and their kinds and imports a module
here only when one of its members is loaded.
"""
