"""Outcome rates on the multi-AV suites: every AV of a road driven by the same decider.

Usage: python scripts/multi_rates.py SUITE[,SUITE...] DECIDER[,DECIDER...] [--limit N]

Runs the first N scenarios of each suite (a name or a .toml path) with each zoo decider through the
benchmark runner, and prints per-AV rates (success / crash / timeout) and joint ones: every AV
succeeds, any AV crashes, any crash between two AVs. The numbers quoted in
envs/suites/{duel,platoon,mixed-traffic}.toml come from it. The rates are
:func:`overtakezoo.benchmark.results.multi_metrics.joint_rates` (which `overtakezoo seeds` and
`overtakezoo decision-rate` use too); this file only prints them.
"""

from __future__ import annotations

import argparse

from overtakezoo.benchmark.results.multi_metrics import run_joint_rates
from overtakezoo.envs.suites import load_suite


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("suites")
    ap.add_argument("deciders")
    ap.add_argument("--limit", type=int, default=200)
    args = ap.parse_args()
    for name in args.suites.split(","):
        suite = load_suite(name)
        for decider in args.deciders.split(","):
            r = run_joint_rates(suite, decider, args.limit)
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
