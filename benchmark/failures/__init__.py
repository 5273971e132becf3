"""Failure search, failure suites, failure maps and the failure board, OpenSCENARIO export (issue 23).

- :mod:`overtakezoo.envs.draws`: a suite's scenario parameters as a search box, and scenarios built from parameter
  values with the distribution's own sampler (one batch, vectorised).
- :mod:`overtakezoo.envs.explicit`: suites that list their scenarios (what a search writes), read and written.
- :mod:`.search`: CMA-ES failure search against random sampling at the same budget.
- :mod:`.board`: the failure cross-table and failure maps of the zoo (``leaderboards/failures/``).
- :mod:`.xosc`: OpenSCENARIO 1.x / OpenDRIVE export of a suite's scenarios, and reading them back.
"""
