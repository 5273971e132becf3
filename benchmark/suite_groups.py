"""The benchmark's policy over the suites: which ones the OvertakeZoo score averages (``CORE``), which
form the multi-AV board (``MULTI``), and the training mixtures of their splits. The simulator
(``envs/suites.py``) reads any suite; what counts on the board is decided here, one layer up.

To put a suite in the score, add its name to ``CORE`` (CONTRIBUTING.md, *Checklist: add a suite*):
every learned member's ``leaderboards/seeds/<member>.json`` must then cover it, or the headline
refuses to render rather than fall back to one run.
"""

from __future__ import annotations

from overtakezoo.envs.config import SuiteError
from overtakezoo.envs.suites import Suite, load_suite

# The public single-ego suites the OvertakeZoo score averages, each weighing the same.
CORE = (
    "table1",
    "table1-reactive",
    "oncoming-2",
    "oncoming-4",
    "oncoming-8",
    "dense",
    "urban-50",
    "adversarial",
    "occluded",
)
# The multi-agent suites: several automated vehicles on one road (not part of the single-ego score).
MULTI = ("duel", "platoon", "mixed-traffic")
# Driver populations: how the other road users drive. Each is a variant of two suites, the single-ego
# ``drivers-<population>`` (table1-reactive's roads) and the multi-AV ``mixed-drivers-<population>``
# (mixed-traffic's); all populations of a family share their roads (one seed), so they differ only in
# the drivers. The zoo trained against the standard drivers; the others are held out (Melting Pot's
# background populations). Their own section of the board, outside the score.
DRIVERS = {
    "standard": "train",
    "timid": "held-out",
    "aggressive": "held-out",
    "slow": "held-out",
    "gap-closer": "held-out",
}
DRIVER_FAMILIES = {"drivers": "table1-reactive", "mixed-drivers": "mixed-traffic"}  # family -> its roads


def driver_suite(name: str) -> tuple[str, str] | None:
    """(family, population) of a driver-population suite's name, else None."""
    for family in sorted(DRIVER_FAMILIES, key=len, reverse=True):  # (mixed-drivers before drivers)
        population = name.removeprefix(f"{family}-")
        if population != name and population in DRIVERS:
            return family, population
    return None


def mixtures() -> dict[str, tuple[str, ...]]:
    """Each group's training mixture: ``core-train`` stands for the training split (``<suite>-train``)
    of every suite in ``CORE``, ``multi-train`` for those of ``MULTI``; read when asked, so a suite
    added to a group joins its mixture."""
    return {"core-train": tuple(f"{n}-train" for n in CORE), "multi-train": tuple(f"{n}-train" for n in MULTI)}


def load_training(spec: str) -> list[Suite]:
    """The suites a trainer draws from: a mixture's name (``core-train``: every core suite's
    training split), suites or mixtures joined by ``+`` (``table1-train+urban-50-train``,
    ``core-train+multi-train``), or one suite."""
    known = mixtures()
    names = tuple(name for part in str(spec).split("+") if part for name in known.get(part, (part,)))
    if not names:
        raise SuiteError(f"no training suite in {spec!r}")
    return [load_suite(n) for n in names]
