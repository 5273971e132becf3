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
    outcome = by_av(per["outcome"], e)
    all_ok = (outcome == SUCCESS).all(axis=0)
    last_done = by_av(per["completion_time"], e).max(axis=0)
    joint = {
        "all_succeed": _rate(all_ok),
        "any_crash": _rate((outcome == CRASH).any(axis=0)),
        "av_crash": _rate((by_av(per["crash_av"], e) >= 0).any(axis=0)),
        "any_yield": _rate(gave_way.any(axis=0)),
        "all_timeout": _rate((outcome == TIMEOUT).all(axis=0)),
        "completion_time": _mean(last_done[all_ok], seed, "joint_completion_time"),
    }
    per_av = [_agent_rows({k: by_av(v, e)[i] for k, v in per.items()}, gave_way[i], seed) for i in range(e)]
    return {**_agent_rows(per, gave_way.reshape(-1), seed), "per_av": per_av, "joint": joint}
