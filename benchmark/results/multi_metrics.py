"""Multi-agent metrics: per-AV and joint (per-road) outcomes of a multi-AV suite, with 95 % CIs.

A multi-AV results file stores every per-scenario array once per AV, *AV-major* as the core lays
out its rows: AV ``e``'s value for scenario ``i`` (of the file's ``n``) is at ``e * n + i``. From
those arrays:

- the Table I rows *per agent*: every metric of :func:`~.metrics.summarize` pooled over all AV
  episodes (``E * n`` of them; in self-play every AV is the same decider), plus the share of crashes
  with another AV (``crash_share_av``) and the yield rate (``yielded``); the same for each AV index
  alone (``per_av``);
- *joint* outcomes, one per road (``n``): every AV succeeds (``all_succeed``), any AV crashes
  (``any_crash``), a crash between two AVs (``av_crash``, counted once per road however many AVs
  it involves), some AV yielded (``any_yield``), every AV timed out (``all_timeout``: nobody got
  through), and the time until the last AV succeeded on roads where all did (``completion_time``).

**Who yielded.** AV ``e`` *yielded* on a road when (1) it did not crash, (2) it aborted at least
once or never entered the opposite lane (``opposite_time`` 0), and (3) another AV of its road
succeeded before it: that AV's completion time is earlier than AV ``e``'s, or AV ``e`` did not
succeed. It is computed from the stored arrays, never stored, so ``leaderboard --verify`` covers it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from overtakezoo.benchmark.results.metrics import TABLE, _mean, _rate, summarize
from overtakezoo.envs import CRASH, SUCCESS, TIMEOUT

# Rows added to Table I for multi-AV results (after the single-ego rows).
MULTI_TABLE = TABLE + [
    ("crash_share_av", "share of crashes with another AV", "rate", "%"),
    ("yielded", "yielded (aborted or never pulled out while another AV passed first)", "rate", "%"),
]
# (key, label, kind, unit) of the joint, per-road outcomes.
JOINT = [
    ("all_succeed", "all AVs succeed", "rate", "%"),
    ("any_crash", "any crash", "rate", "%"),
    ("av_crash", "AV-AV crash", "rate", "%"),
    ("any_yield", "an AV yielded", "rate", "%"),
    ("all_timeout", "all AVs time out", "rate", "%"),
    ("completion_time", "time until all succeeded", "mean", "s"),
]


def by_av(a: np.ndarray, num_avs: int) -> np.ndarray:
    """An AV-major per-scenario array (E * n,) as (E, n): row e is AV e."""
    return np.asarray(a).reshape(num_avs, -1)


def joint_masks(per: dict[str, np.ndarray], num_avs: int) -> dict[str, np.ndarray]:
    """The per-road joint outcomes as (n,) bool masks: every AV succeeds (``all_succeed``), any AV
    crashes (``any_crash``), a crash between two AVs (``av_crash``); and ``outcome`` as (E, n). A
    results file without ``crash_av`` (a single-AV run) has no AV-AV crash."""
    outcome = by_av(per["outcome"], num_avs)
    crash_av = by_av(per["crash_av"], num_avs) if "crash_av" in per else np.full(outcome.shape, -1)
    return {
        "outcome": outcome,
        "all_succeed": (outcome == SUCCESS).all(axis=0),
        "any_crash": (outcome == CRASH).any(axis=0),
        "av_crash": (crash_av >= 0).any(axis=0),
    }


def joint_rates(per: dict[str, np.ndarray], num_avs: int) -> dict[str, Any]:
    """Joint and per-AV outcome rates of one run (every AV of a road driven by the same decider), to
    3 decimals, with the outcome ``counts`` behind them: the plain numbers a seeds file, a decision-rate
    score and ``scripts/multi_rates.py`` read (:func:`summarize_multi` gives the same with CIs)."""
    m = joint_masks(per, num_avs)
    outcome = m["outcome"]
    e, n = outcome.shape

    def mean(mask: np.ndarray) -> float:
        return round(float(mask.mean()), 3)

    return {
        "scenarios": n,
        "all_succeed": mean(m["all_succeed"]),
        "any_crash": mean(m["any_crash"]),
        "av_av_crash": mean(m["av_crash"]),
        "per_av": [
            {"success": mean(o == SUCCESS), "crash": mean(o == CRASH), "timeout": mean(o == TIMEOUT)} for o in outcome
        ],
        "counts": {
            "roads": n,
            "av_rows": e * n,
            "success": int((outcome == SUCCESS).sum()),
            "crash": int((outcome == CRASH).sum()),
            "timeout": int((outcome == TIMEOUT).sum()),
            "all_succeed": int(m["all_succeed"].sum()),
            "any_crash": int(m["any_crash"].sum()),
            "av_av_crash": int(m["av_crash"].sum()),
        },
    }


def run_joint_rates(suite: Any, decider: Any, limit: int | None = None, **on: Any) -> dict[str, Any]:
    """:func:`joint_rates` of ``decider`` (a zoo name or a loaded decider) driving every AV of
    ``suite``'s first ``limit`` scenarios (None: all) through the benchmark runner (``on``: its
    ``device`` / ``backend`` keywords)."""
    from overtakezoo.benchmark.run.runner import run_suite
    from overtakezoo.zoo.base import load

    if isinstance(decider, str):
        decider = load(decider, suite.config)
    return joint_rates(run_suite(suite, decider, progress=False, limit=limit, **on).per, suite.num_avs)


def yielded(per: dict[str, np.ndarray], num_avs: int) -> np.ndarray:
    """(E, n) bool: AV e yielded on road i (see the module docstring)."""
    outcome = by_av(per["outcome"], num_avs)
    success = outcome == SUCCESS
    done_at = np.where(success, by_av(per["completion_time"], num_avs), np.inf)
    held_back = (by_av(per["aborts"], num_avs) > 0) | (by_av(per["opposite_time"], num_avs) == 0)
    # another AV of the road succeeded strictly earlier (an AV is never earlier than itself)
    passed_first = (done_at[None, :, :] < done_at[:, None, :]).any(axis=1)
    return (outcome != CRASH) & held_back & passed_first


def _agent_rows(per: dict[str, np.ndarray], gave_way: np.ndarray, seed: int) -> dict[str, Any]:
    """Table I of a set of AV episodes, with the multi-AV rows."""
    crash = per["outcome"] == CRASH
    return {**summarize(per, seed), "crash_share_av": _rate(per["crash_av"] >= 0, crash), "yielded": _rate(gave_way)}


def summarize_multi(per: dict[str, np.ndarray], seed: int, num_avs: int) -> dict[str, Any]:
    """Pooled per-agent Table I, one per AV index (``per_av``) and the joint outcomes (``joint``)."""
    e = num_avs
    gave_way = yielded(per, e)
    m = joint_masks(per, e)
    all_ok = m["all_succeed"]
    last_done = by_av(per["completion_time"], e).max(axis=0)
    joint = {
        "all_succeed": _rate(all_ok),
        "any_crash": _rate(m["any_crash"]),
        "av_crash": _rate(m["av_crash"]),
        "any_yield": _rate(gave_way.any(axis=0)),
        "all_timeout": _rate((m["outcome"] == TIMEOUT).all(axis=0)),
        "completion_time": _mean(last_done[all_ok], seed, "joint_completion_time"),
    }
    per_av = [_agent_rows({k: by_av(v, e)[i] for k, v in per.items()}, gave_way[i], seed) for i in range(e)]
    return {**_agent_rows(per, gave_way.reshape(-1), seed), "per_av": per_av, "joint": joint}
