"""Failure search against random sampling: distinct crashes per simulated episode, per zoo decider.

    python scripts/failure_search_ratio.py [--budget 2000] [--out docs/failure-search-ratio]

For each (suite, decider) of ROWS: three seeds of the CMA-ES failure search (`overtakezoo search`) and
three seeds of random sampling of the suite, each at the same budget, the same evaluation and the
same deduplication (benchmark/failures/search.py, ``compare``); the ratio of the pooled rates. Writes
OUT.json and OUT.md with the machine and the load. The perf report's ``failure-search-*`` rows
(benchmark/failures/perf_rows.py) are the same measurement for table1/fuzzy and table1/ppo.
"""

from __future__ import annotations

import argparse
import sys
import time

from overtakezoo import zoo
from overtakezoo.benchmark.failures.search import compare
from overtakezoo.benchmark.run.perf import load_average, machine
from overtakezoo.envs.io import atomic_write_json, atomic_write_text
from overtakezoo.envs.suites import load_suite

# The zoo members under 5 % crashes on table1 (leaderboards/table1.md: fuzzy 0.2 %, double-dqn 0.5 %,
# ppo 1.4 %, ps-dqn 2.8 %; the shielded ppo+shield 0.0 % and rule-fsm+shield 0.1 %), then two on oncoming-4.
ROWS = [
    ("table1", "fuzzy"),
    ("table1", "ppo"),
    ("table1", "double-dqn"),
    ("table1", "ps-dqn"),
    ("table1", "ppo+shield"),
    ("table1", "rule-fsm+shield"),
    ("oncoming-4", "fuzzy"),
    ("oncoming-4", "ppo"),
]
SEEDS = [0, 1, 2]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--budget", type=int, default=2000)
    p.add_argument("--out", default="docs/failure-search-ratio")
    args = p.parse_args(argv)
    started = time.perf_counter()
    meta = {
        "machine": machine(),
        "date": time.strftime("%Y-%m-%d %H:%M"),
        "load_average_at_start": load_average(),
        "budget": args.budget,
        "seeds": SEEDS,
    }
    rows = []
    for suite_name, decider_name in ROWS:
        suite = load_suite(suite_name)
        t0 = time.perf_counter()
        r = compare(suite, zoo.load(decider_name, suite.config), args.budget, SEEDS, SEEDS)
        r["wall_s"] = round(time.perf_counter() - t0, 1)
        rows.append(r)
        print(
            f"{suite_name} {decider_name}: search {[s['distinct'] for s in r['search']]} random "
            f"{[s['distinct'] for s in r['random']]} ratio {r['ratio'] or r['ratio_at_least']:.1f}"
            f"{'' if r['ratio'] else ' (at least)'} ({r['wall_s']} s)",
            file=sys.stderr,
            flush=True,
        )
    meta["load_average_at_end"] = load_average()
    meta["wall_s"] = round(time.perf_counter() - started, 1)
    doc = {**meta, "rows": rows}
    atomic_write_json(args.out + ".json", doc)
    atomic_write_text(args.out + ".md", markdown(doc))
    print(f"wrote {args.out}.json and {args.out}.md")
    return 0


def markdown(doc: dict) -> str:
    m, b = doc["machine"], doc["budget"]
    seeds = ", ".join(map(str, doc["seeds"]))
    out = [
        "# Failure search against random sampling",
        "",
        f"Written by `python scripts/failure_search_ratio.py --budget {b}` on {doc['date']}: {m['cpu']}, "
        f"{m['cores']} cores, Python {m['python']}, numpy {m['numpy']}; load average {doc['load_average_at_start']} "
        f"at the start, {doc['load_average_at_end']} at the end; {doc['wall_s']} s in all.",
        "",
        f"Per row: the CMA-ES failure search (`overtakezoo search --decider D --suite S --budget {b} --seed K`, "
        f"K = {seeds}) and random sampling of the suite (its own sampler, seeds 10000 + K), {b} episodes each. "
        "A failure is a crash (or leaving the road), counted once if it is within 5 % of every range of an "
        "earlier one. *Ratio*: distinct failures per episode of the search over those of random sampling, each "
        "pooled over its three runs.",
        "",
        "| suite | decider | search: distinct crashes per run | random: per run | search per 100 episodes | "
        "random per 100 episodes | ratio | wall time of a search |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in doc["rows"]:
        ratio = f"{r['ratio']:.1f}x" if r["ratio"] is not None else f">= {r['ratio_at_least']:.1f}x (random found none)"
        wall = sum(s["wall_s"] for s in r["search"]) / len(r["search"])
        out.append(
            f"| {r['suite']} | {r['decider']} | {', '.join(str(s['distinct']) for s in r['search'])} | "
            f"{', '.join(str(s['distinct']) for s in r['random'])} | {100 * r['search_rate']:.2f} | "
            f"{100 * r['random_rate']:.2f} | {ratio} | {wall:.1f} s |"
        )
    return "\n".join(out) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
