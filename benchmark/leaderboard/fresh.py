"""Fresh draws: a row's policy on scenarios of its suite's distribution that nobody knew in advance.

Every suite is public with a fixed seed, and a scenario is identifiable from its first observation,
so a policy could map the public scenarios to their answers and top the board without driving any
better. The distribution is public too, so the board also runs every row on draws nobody could know
when the policy was made:

- ``submit`` records one **fresh draw** in the row (``submission.fresh``): the suite's distribution and
  settings with a seed from fresh randomness and ``min(FRESH_COUNT, count)`` scenarios, and the outcome
  of every scenario (and AV). The pages show its success and crash rates beside the public ones.
- A row whose fresh draw and public suite disagree (:func:`disagreement`: success or crash rate more
  than ``Z_LIMIT`` standard errors apart) is **flagged**: listed apart with both figures, never ranked,
  and out of the headline score. So is a row with no fresh draw recorded.
- ``leaderboard --verify`` re-runs the recorded draw like the public scenarios (its outcomes must
  reproduce), and runs ``CHECK_COUNT`` scenarios of a draw of its own (a seed chosen at verify time and
  printed), which must agree with the recorded one: a recorded seed picked because the policy
  memorised its scenarios too is refused. A recorded seed may not be a built-in suite's.

The test is a two-proportion z-test with the pooled rate. At ``Z_LIMIT = 5`` an honest row is flagged or
refused with probability about 6e-7 per rate and comparison (under 1e-3 over a board of a few hundred
rows), while a policy that fell from 99 % on the public scenarios to 80 % on 500 fresh ones is at z = 13.
"""

from __future__ import annotations

import dataclasses
import math
import zlib
from typing import Any

import numpy as np

from overtakezoo.envs.model.outcomes import CRASH, SUCCESS
from overtakezoo.envs.suites import Suite, load_suite, suite_names

FRESH_COUNT = 500  # scenarios of a row's recorded fresh draw (all of a smaller suite's count)
CHECK_COUNT = 200  # scenarios of the draw verify makes itself, per suite
Z_LIMIT = 5.0  # standard errors apart before two draws disagree (module docstring)


def fresh_suite(suite: Suite, seed: int, count: int) -> Suite:
    """``suite``'s distribution and simulator settings drawn with another seed and count."""
    return dataclasses.replace(suite, seed=int(seed), count=int(count))


def public_seeds() -> frozenset[int]:
    """Every built-in suite's seed (test suites and training splits): a fresh draw is none of them."""
    return frozenset(load_suite(name).seed for name in suite_names())


def fresh_count(suite: Suite) -> int:
    return min(FRESH_COUNT, suite.count)


def check_seed(seed: int, suite_name: str) -> int:
    """Verify's own draw of one suite, from its run's seed (printed) and the suite's name."""
    return int(np.random.SeedSequence([seed, zlib.crc32(suite_name.encode())]).generate_state(1, np.uint64)[0] >> 1)


def encode(outcome: np.ndarray) -> str:
    """Per-scenario outcome codes (1-4) as the row stores them: one digit each."""
    return "".join(map(str, np.asarray(outcome, np.int64).tolist()))


def decode(text: str) -> np.ndarray:
    return np.frombuffer(text.encode("ascii"), np.uint8).astype(np.int64) - ord("0")


def block(seed: int, count: int, outcome: np.ndarray) -> dict[str, Any]:
    """The ``submission.fresh`` block of a row."""
    return {"seed": int(seed), "count": int(count), "outcomes": encode(outcome)}


def rates(outcome: np.ndarray) -> dict[str, Any]:
    """Counts of a draw: ``n`` (scenarios x AVs), ``success`` and ``crash``."""
    outcome = np.asarray(outcome)
    return {
        "n": int(outcome.size),
        "success": int(np.count_nonzero(outcome == SUCCESS)),
        "crash": int(np.count_nonzero(outcome == CRASH)),
    }


def z_score(k1: int, n1: int, k2: int, n2: int) -> float:
    """Two-proportion z statistic with the pooled rate (0 when both rates are 0 or both 1)."""
    p = (k1 + k2) / (n1 + n2)
    se = math.sqrt(p * (1.0 - p) * (1.0 / n1 + 1.0 / n2))
    return 0.0 if se == 0.0 else abs(k1 / n1 - k2 / n2) / se


def disagreement(a: dict[str, Any], b: dict[str, Any]) -> str | None:
    """Why the draws with counts ``a`` and ``b`` (:func:`rates`) disagree, or None when they agree."""
    for key in ("success", "crash"):
        z = z_score(a[key], a["n"], b[key], b["n"])
        if z >= Z_LIMIT:
            return (
                f"{key} rate {100 * a[key] / a['n']:.1f} % of {a['n']} against {100 * b[key] / b['n']:.1f} % "
                f"of {b['n']} (z = {z:.1f}, the limit is {Z_LIMIT:g})"
            )
    return None


def recorded(results: Any) -> dict[str, Any] | None:
    """A row's ``submission.fresh`` block, or None."""
    return (results.meta.get("submission") or {}).get("fresh")


def flag(results: Any) -> str | None:
    """Why a row cannot rank (its fresh draw disagrees with its public scenarios, or it has none), or None."""
    fresh = recorded(results)
    if fresh is None:
        return "no fresh draw recorded (re-file it with `overtakezoo submit --replace`)"
    why = disagreement(rates(decode(fresh["outcomes"])), rates(results.per["outcome"]))
    return None if why is None else f"fresh draw against the public suite: {why}"


def summary(results: Any) -> dict[str, Any] | None:
    """The fresh draw's figures for the pages (seed, counts, rates), or None."""
    fresh = recorded(results)
    if fresh is None:
        return None
    r = rates(decode(fresh["outcomes"]))
    return {
        "seed": fresh["seed"],
        "count": fresh["count"],
        **r,
        "success_rate": r["success"] / r["n"],
        "crash_rate": r["crash"] / r["n"],
    }


def cell(results: Any) -> str:
    """The fresh draw's column on a page: success / crash rate and the scenarios it ran."""
    s = summary(results)
    if s is None:
        return "-"
    return f"{100 * s['success_rate']:.1f} % / {100 * s['crash_rate']:.1f} % ({s['count']})"


def shape_error(results: Any, suite: Suite, public_seeds: set[int]) -> str | None:
    """What is wrong with a row's recorded fresh block for ``suite`` (its length, its seed), or None."""
    fresh = recorded(results)
    if fresh is None:
        return "submission.fresh: missing: every row records a fresh draw (re-file it with `overtakezoo submit`)"
    if fresh["count"] != fresh_count(suite):
        return (
            f"submission.fresh.count: {fresh['count']} scenarios "
            f"(a fresh draw of {suite.name} has {fresh_count(suite)})"
        )
    if len(fresh["outcomes"]) != fresh["count"] * suite.num_avs:
        return (
            f"submission.fresh.outcomes: {len(fresh['outcomes'])} values (the draw gives {fresh['count']} "
            f"scenarios x {suite.num_avs} AV)"
        )
    if fresh["seed"] in public_seeds:
        return f"submission.fresh.seed: {fresh['seed']} is a built-in suite's seed, not a fresh draw"
    return None


def run_fresh(
    suite: Suite,
    decider: Any,
    seed: int,
    count: int | None = None,
    device: str | None = None,
    backend: str | None = None,
) -> np.ndarray:
    """The outcome of every scenario (and AV, AV-major) of ``decider`` on a fresh draw of ``suite``, on
    the core ``device`` / ``backend`` pick (the runner's keywords; None: the numpy core)."""
    from overtakezoo.benchmark.run.runner import run_indices

    draw = fresh_suite(suite, seed, fresh_count(suite) if count is None else count)
    return run_indices(draw, decider, np.arange(draw.count), safety=False, device=device, backend=backend)["outcome"]
