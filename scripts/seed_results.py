"""Evaluate every training seed of the learned members and pick the seed to ship.

Usage: python scripts/seed_results.py MEMBER RUN_DIR [RUN_DIR ...] [--ship] [--suites a,b,...]

Each RUN_DIR is an ``overtakezoo train`` output (``<algo>.pt`` + ``<algo>.json``, and from newer
trainers ``<algo>.npz``). Every seed is run on the training splits of the core suites
(``core-train``, what the members train on) and on the core suites; the outcome counts and CIs go to
``leaderboards/seeds/<MEMBER>.json``, which the leaderboard reads to report the member as the mean
and spread over seeds. With ``--ship`` the selected seed is exported
(:func:`overtakezoo.zoo.export.export`) into ``zoo/pretrained/<MEMBER>.npz`` + ``.json``.

Selection rule (fixed before any seed was evaluated): the median seed by mean success rate over the
*training* splits (ties: lower mean crash rate there, then the lower seed). The test suites never
enter the choice.
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

from overtakezoo.benchmark.headline import CORE
from overtakezoo.benchmark.io import atomic_write_bytes
from overtakezoo.benchmark.policy import load_policy
from overtakezoo.benchmark.runner import run_suite
from overtakezoo.benchmark.suites import MIXTURES, load_suite
from overtakezoo.zoo.export import export, trained_sha256

ROOT = Path(__file__).resolve().parents[1]
TRAIN_SUITE = "core-train"
TRAIN_SPLITS = MIXTURES[TRAIN_SUITE]
RULE = ("the median seed by mean success rate over the training splits of the core suites (core-train; ties: "
        "lower mean crash rate there, then the lower seed), fixed before any seed was evaluated; test suites "
        "never enter the choice")


def counts(summary: dict) -> dict:
    s, c = summary["success_rate"], summary["crash_rate"]
    return {"n": s["n"], "success": s["k"], "crash": c["k"], "success_rate": s["value"],
            "success_ci": [s["lo"], s["hi"]], "crash_rate": c["value"], "crash_ci": [c["lo"], c["hi"]],
            "crash_share_npc1": summary["crash_share_npc1"]["value"],
            "crash_share_npc2": summary["crash_share_npc2"]["value"]}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("member")
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--ship", action="store_true")
    ap.add_argument("--suites", default=",".join(CORE))
    ap.add_argument("--no-write", action="store_true", help="only evaluate (fill each run's cache)")
    args = ap.parse_args()
    algo = args.member
    seeds = []
    for run in args.runs:
        card = json.loads((run / f"{algo}.json").read_text())
        weights_sha = trained_sha256(card)  # the torch file's: the same before and after an export
        entry = {"seed": card["seed"], "run": run.name, "weights_sha256": weights_sha,
                 "steps": card.get("steps", card.get("training", {}).get("gradient_steps")), "suites": {}}
        cache_path = run / "seed-eval.json"  # a run's evaluations, reused while weights and suites match
        cache = json.loads(cache_path.read_text()) if cache_path.is_file() else {}
        for name in [*TRAIN_SPLITS, *args.suites.split(",")]:
            suite = load_suite(name)
            hit = cache.get(name)
            if hit and hit["suite_sha256"] == suite.hash and cache.get("weights_sha256") == weights_sha:
                entry["suites"][name] = hit
                continue
            weights = run / f"{algo}.npz" if (run / f"{algo}.npz").is_file() else run / f"{algo}.pt"
            results = run_suite(suite, load_policy(str(weights), suite.config), progress=False)
            entry["suites"][name] = {"suite_version": suite.version, "suite_sha256": suite.hash,
                                     **counts(results.summary)}
            print(f"{algo} seed {card['seed']} {name}: success {results.summary['success_rate']['value']:.4f} "
                  f"crash {results.summary['crash_rate']['value']:.4f}", flush=True)
        atomic_write_bytes(cache_path, json.dumps({"weights_sha256": weights_sha,
                                                   **entry["suites"]}, indent=1).encode())
        seeds.append(entry)
    if args.no_write:
        return
    def train_mean(e: dict, rate: str) -> float:
        return sum(e["suites"][n][rate] for n in TRAIN_SPLITS) / len(TRAIN_SPLITS)

    order = sorted(seeds, key=lambda e: (train_mean(e, "success_rate"), -train_mean(e, "crash_rate"), -e["seed"]))
    chosen = order[(len(order) - 1) // 2]
    doc = {"member": algo, "selection_rule": RULE, "shipped_seed": chosen["seed"], "train_suite": TRAIN_SUITE,
           "seeds": sorted(seeds, key=lambda e: e["seed"])}
    atomic_write_bytes(ROOT / "leaderboards" / "seeds" / f"{algo}.json",
                       (json.dumps(doc, indent=1, sort_keys=True) + "\n").encode())
    print(f"{algo}: shipped seed {chosen['seed']} ({chosen['run']})")
    if args.ship:
        run = next(r for r in args.runs if r.name == chosen["run"])
        note = (f"Seed {chosen['seed']} of {len(seeds)} training seeds "
                f"({', '.join(str(e['seed']) for e in doc['seeds'])}), chosen by the rule above.")
        seed_results = {str(e["seed"]): {k: e["suites"][k] for k in e["suites"]} for e in doc["seeds"]}
        # The shipped seed's results on every suite it was run on, in the card's summary form.
        results = {k: {**v, "count": v["n"]} for k, v in chosen["suites"].items()}
        updates = {"selection_rule": RULE, "selection_note": note, "seed_results": seed_results, "results": results}
        dest = ROOT / "zoo" / "pretrained"
        if (run / f"{algo}.pt").is_file():  # a torch trainer's output: export it to numpy
            card = export(run, dest, algo, updates)
        else:  # bc / cql write their .npz directly: publish it as it is, the card completed
            shutil.copyfile(run / f"{algo}.npz", dest / f"{algo}.npz")
            card = dest / f"{algo}.json"
            atomic_write_bytes(card, (json.dumps({**json.loads((run / f"{algo}.json").read_text()), **updates},
                                                 indent=1, sort_keys=True) + "\n").encode())
        print(f"{algo}: published {run.name} as {card.with_suffix('.npz')} + {card.name}")


if __name__ == "__main__":
    main()
