"""Outcome rates on the multi-AV suites: every AV of a road driven by the same decider.

Usage: python scripts/multi_rates.py SUITE[,SUITE...] DECIDER[,DECIDER...] [--limit N]

Runs the first N scenarios of each suite (a name or a .toml path) with each zoo decider through the
benchmark runner, and prints per-AV rates
(success / crash / timeout) and joint ones: every AV succeeds, any AV crashes, any crash between
two AVs. The numbers quoted in envs/suites/{duel,platoon,mixed-traffic}.toml come from it;
scripts/seed_results.py calls :func:`rates` for the multi-AV suites (every seed of a member).
"""

from __future__ import annotations

import argparse

import numpy as np

from overtakezoo.benchmark.results.multi_metrics import by_av
from overtakezoo.benchmark.run.runner import run_suite
from overtakezoo.envs import CRASH, SUCCESS, TIMEOUT
from overtakezoo.envs.suites import Suite, load_suite
from overtakezoo.zoo.base import Decider, load


def rates(suite: Suite, decider_name: str | Decider, limit: int | None) -> dict[str, object]:
    """Joint and per-AV outcome rates of a zoo decider (by name, or a loaded one) driving every AV
    on the first ``limit`` scenarios (None: all), as the benchmark runner measures them; ``counts``
    holds the outcome counts behind them."""
    decider = load(decider_name, suite.config) if isinstance(decider_name, str) else decider_name
    per = run_suite(suite, decider, progress=False, limit=limit).per
    outcome = by_av(per["outcome"], suite.num_avs)
    # A single-AV suite records no AV-AV crashes (-1: none), so its rates read the same way.
    crash_av = by_av(per["crash_av"], suite.num_avs) if "crash_av" in per else np.full(outcome.shape, -1)
    e, n = outcome.shape

    def mean(mask: np.ndarray) -> float:
        return round(float(mask.mean()), 3)

    return {
        "scenarios": n,
        "all_succeed": mean((outcome == SUCCESS).all(0)),
        "any_crash": mean((outcome == CRASH).any(0)),
        "av_av_crash": mean((crash_av >= 0).any(0)),
        "per_av": [
            {"success": mean(o == SUCCESS), "crash": mean(o == CRASH), "timeout": mean(o == TIMEOUT)} for o in outcome
        ],
        "counts": {
            "roads": n,
            "av_rows": e * n,
            "success": int((outcome == SUCCESS).sum()),
            "crash": int((outcome == CRASH).sum()),
            "timeout": int((outcome == TIMEOUT).sum()),
            "all_succeed": int((outcome == SUCCESS).all(0).sum()),
            "any_crash": int((outcome == CRASH).any(0).sum()),
            "av_av_crash": int((crash_av >= 0).any(0).sum()),
        },
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("suites")
    ap.add_argument("deciders")
    ap.add_argument("--limit", type=int, default=200)
    args = ap.parse_args()
    for name in args.suites.split(","):
        suite = load_suite(name)
        for decider in args.deciders.split(","):
            r = rates(suite, decider, args.limit)
            per_av = "  ".join(
                f"av{i} " + " ".join(f"{k} {v:.2f}" for k, v in av.items()) for i, av in enumerate(r["per_av"])
            )
            print(
                f"{suite.name} {decider} n={r['scenarios']}: all succeed {r['all_succeed']:.2f}, any crash "
                f"{r['any_crash']:.2f}, AV-AV crash {r['av_av_crash']:.2f} | {per_av}",
                flush=True,
            )


if __name__ == "__main__":
    main()
