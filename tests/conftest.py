"""Shared test setup: one fixed Hypothesis profile for every run (CI and local).

Derandomized (the examples follow from each test's source, not from a random seed) with no example
database, so ``python -m pytest`` on a fresh clone tries the same inputs every time: a fuzz test
either always passes or always fails. ``print_blob`` prints a failing example's reproduction blob.
Tests may still set their own ``max_examples`` with ``@settings``; the rest comes from here.
"""

from hypothesis import HealthCheck, settings

settings.register_profile(
    "overtakezoo",
    derandomize=True,
    database=None,
    max_examples=100,
    deadline=None,
    print_blob=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile("overtakezoo")
