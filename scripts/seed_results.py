"""Evaluate every training seed of the learned members and pick the seed to ship.

Usage: python scripts/seed_results.py MEMBER RUN_DIR [RUN_DIR ...] [--ship] [--suites a,b,...]
       [--train-suite SPEC] [--compare NAME,NAME,...]
       python scripts/seed_results.py MEMBER --compare-only --compare NAME   # after NAME was retrained

Each RUN_DIR is an ``overtakezoo train`` output (``<algo>.pt`` + ``<algo>.json``, and from newer
trainers ``<algo>.npz``). Every seed is run on the training splits of the suites it trained on
(``--train-suite``, default ``core-train``, what the single-agent members train on) and on the core
suites (or ``--suites``); the outcome counts and CIs go to ``leaderboards/seeds/<MEMBER>.json``,
which the leaderboard reads to report the member as the mean and spread over seeds. With
``--ship`` the selected seed is exported (:func:`overtakezoo.zoo.train.export.export`) into
``zoo/pretrained/<MEMBER>.npz`` + ``.json``.

A multi-AV suite (``duel``, ``platoon``, ``mixed-traffic`` and their training splits) is run with
every AV driven by the seed (self-play, ``scripts/multi_rates.py``); its rates are per AV, with the
joint ones beside them (every AV of a road succeeds, a crash between two AVs). ``--compare`` runs
the named zoo members (their shipped weights) on the same multi-AV suites, for the member's card.

Selection rule (fixed before any seed was evaluated): the median seed by mean success rate over the
*training* splits (ties: lower mean crash rate there, then the lower seed). The test suites never
enter the choice.
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

from multi_rates import rates as multi_rates  # this script's folder is on sys.path

from overtakezoo.benchmark.run.policy import load_policy
from overtakezoo.benchmark.run.runner import run_suite
from overtakezoo.envs.io import atomic_write_bytes
from overtakezoo.envs.suites import CORE, MIXTURES, load_suite, load_training
from overtakezoo.zoo.train.export import export, trained_sha256

ROOT = Path(__file__).resolve().parents[1]
TRAIN_SUITE = "core-train"
TRAIN_SPLITS = MIXTURES[TRAIN_SUITE]
RULE = (
    "the median seed by mean success rate over the training splits of the core suites (core-train; ties: "
    "lower mean crash rate there, then the lower seed), fixed before any seed was evaluated; test suites "
    "never enter the choice"
)


def rule(train_suite: str) -> str:
    """The selection rule's text for a member trained on ``train_suite`` (RULE for core-train)."""
    if train_suite == TRAIN_SUITE:
        return RULE
    return (
        f"the median seed by mean success rate over the training splits it trained on ({train_suite}, per "
        "AV on the multi-AV splits; ties: lower mean crash rate there, then the lower seed), fixed before any "
        "seed was evaluated; test suites never enter the choice"
    )


def counts(summary: dict) -> dict:
    s, c = summary["success_rate"], summary["crash_rate"]
    return {
        "n": s["n"],
        "success": s["k"],
        "crash": c["k"],
        "success_rate": s["value"],
        "success_ci": [s["lo"], s["hi"]],
        "crash_rate": c["value"],
        "crash_ci": [c["lo"], c["hi"]],
        "crash_share_npc1": summary["crash_share_npc1"]["value"],
        "crash_share_npc2": summary["crash_share_npc2"]["value"],
    }


def multi_counts(suite, decider) -> dict:
    """Per-AV and joint outcomes of ``decider`` driving every AV of the whole multi-AV ``suite``."""
    c = multi_rates(suite, decider, None)["counts"]
    n, roads = c["av_rows"], c["roads"]
    return {
        "n": n,
        "roads": roads,
        "success": c["success"],
        "crash": c["crash"],
        "success_rate": c["success"] / n,
        "crash_rate": c["crash"] / n,
        "timeout_rate": c["timeout"] / n,
        "all_succeed": c["all_succeed"],
        "all_succeed_rate": c["all_succeed"] / roads,
        "av_av_crash": c["av_av_crash"],
        "av_av_crash_rate": c["av_av_crash"] / roads,
        "any_crash_rate": c["any_crash"] / roads,
    }


def evaluate(suite, decider) -> dict:
    """The counts of one suite: the runner's summary, or per-AV rates on a multi-AV suite."""
    if suite.scenarios().num_avs > 1:
        return multi_counts(suite, decider)
    return counts(run_suite(suite, decider, progress=False).summary)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("member")
    ap.add_argument("runs", nargs="*", type=Path)
    ap.add_argument("--ship", action="store_true")
    ap.add_argument("--suites", default=",".join(CORE))
    ap.add_argument("--no-write", action="store_true", help="only evaluate (fill each run's cache)")
    ap.add_argument(
        "--train-suite", default=TRAIN_SUITE, help="what the member trained on (its splits choose the seed)"
    )
    ap.add_argument("--compare", default="", help="zoo members to run on the multi-AV suites beside it")
    ap.add_argument(
        "--compare-only",
        action="store_true",
        help="re-run only the --compare members (after one "
        "was retrained) and update the seeds file and the shipped card; the member's seeds stay",
    )
    args = ap.parse_args()
    algo = args.member
    if args.compare_only:
        return compare_only(algo, args.compare.split(","))
    if not args.runs:
        ap.error("give the member's run directories")
    train_splits = [s.name for s in load_training(args.train_suite)]
    seeds = []
    for run in args.runs:
        card = json.loads((run / f"{algo}.json").read_text())
        weights_sha = trained_sha256(card)  # the torch file's: the same before and after an export
        entry = {
            "seed": card["seed"],
            "run": run.name,
            "weights_sha256": weights_sha,
            "steps": card.get("steps", card.get("training", {}).get("gradient_steps")),
            "suites": {},
        }
        cache_path = run / "seed-eval.json"  # a run's evaluations, reused while weights, deployment and suites match
        cache = json.loads(cache_path.read_text()) if cache_path.is_file() else {}
        # how the card deploys the network (scripts/decision_rate.py): rate and OVERTAKE threshold
        deployed = {k: card.get(k) for k in ("decide_every", "overtake_offset")}
        if cache.get("deployed") != deployed:
            cache = {}
        for name in dict.fromkeys([*train_splits, *args.suites.split(",")]):
            suite = load_suite(name)
            hit = cache.get(name)
            if hit and hit["suite_sha256"] == suite.hash and cache.get("weights_sha256") == weights_sha:
                entry["suites"][name] = hit
                continue
            weights = run / f"{algo}.npz" if (run / f"{algo}.npz").is_file() else run / f"{algo}.pt"
            got = evaluate(suite, load_policy(str(weights), suite.config))
            entry["suites"][name] = {"suite_version": suite.version, "suite_sha256": suite.hash, **got}
            joint = f" AV-AV crash {got['av_av_crash_rate']:.4f}" if "av_av_crash" in got else ""
            print(
                f"{algo} seed {card['seed']} {name}: success {got['success_rate']:.4f} "
                f"crash {got['crash_rate']:.4f}{joint}",
                flush=True,
            )
        atomic_write_bytes(
            cache_path,
            json.dumps({"weights_sha256": weights_sha, "deployed": deployed, **entry["suites"]}, indent=1).encode(),
        )
        seeds.append(entry)
    if args.no_write:
        return

    def train_mean(e: dict, rate: str) -> float:
        return sum(e["suites"][n][rate] for n in train_splits) / len(train_splits)

    order = sorted(seeds, key=lambda e: (train_mean(e, "success_rate"), -train_mean(e, "crash_rate"), -e["seed"]))
    chosen = order[(len(order) - 1) // 2]
    doc = {
        "member": algo,
        "selection_rule": rule(args.train_suite),
        "shipped_seed": chosen["seed"],
        "train_suite": args.train_suite,
        "seeds": sorted(seeds, key=lambda e: e["seed"]),
    }
    multi = [n for n in args.suites.split(",") if load_suite(n).scenarios().num_avs > 1]
    if args.compare and multi:
        doc["compare"] = {other: compare(other, multi) for other in args.compare.split(",")}
    if multi:
        print(comparison_table(doc, multi))
    atomic_write_bytes(
        ROOT / "leaderboards" / "seeds" / f"{algo}.json", (json.dumps(doc, indent=1, sort_keys=True) + "\n").encode()
    )
    print(f"{algo}: shipped seed {chosen['seed']} ({chosen['run']})")
    if args.ship:
        run = next(r for r in args.runs if r.name == chosen["run"])
        note = (
            f"Seed {chosen['seed']} of {len(seeds)} training seeds "
            f"({', '.join(str(e['seed']) for e in doc['seeds'])}), chosen by the rule above."
        )
        seed_results = {str(e["seed"]): {k: e["suites"][k] for k in e["suites"]} for e in doc["seeds"]}
        # The shipped seed's results on every suite it was run on, in the card's summary form.
        results = {k: {**v, "count": v["n"]} for k, v in chosen["suites"].items()}
        updates = {
            "selection_rule": doc["selection_rule"],
            "selection_note": note,
            "seed_results": seed_results,
            "results": results,
        }
        if "compare" in doc:  # the single-agent members in self-play on the same multi-AV suites
            updates["multi_av_comparison"] = {"table": comparison_table(doc, multi).splitlines(), **doc["compare"]}
        dest = ROOT / "zoo" / "pretrained"
        if (run / f"{algo}.pt").is_file():  # a torch trainer's output: export it to numpy
            card = export(run, dest, algo, updates)
        else:  # bc / cql write their .npz directly: publish it as it is, the card completed
            shutil.copyfile(run / f"{algo}.npz", dest / f"{algo}.npz")
            card = dest / f"{algo}.json"
            atomic_write_bytes(
                card,
                (
                    json.dumps({**json.loads((run / f"{algo}.json").read_text()), **updates}, indent=1, sort_keys=True)
                    + "\n"
                ).encode(),
            )
        print(f"{algo}: published {run.name} as {card.with_suffix('.npz')} + {card.name}")


def compare(other: str, multi: list[str]) -> dict:
    """The zoo member ``other`` (its shipped weights) in self-play on each multi-AV suite."""
    out = {}
    for name in multi:
        suite = load_suite(name)
        got = multi_counts(suite, load_policy(other, suite.config))
        out[name] = {"suite_version": suite.version, "suite_sha256": suite.hash, **got}
        print(
            f"{other} {name}: success {got['success_rate']:.4f} crash {got['crash_rate']:.4f} "
            f"AV-AV crash {got['av_av_crash_rate']:.4f}",
            flush=True,
        )
    return out


def compare_only(algo: str, others: list[str]) -> None:
    """Re-run the compared members ``others`` on the multi-AV suites of ``algo``'s seeds file and
    update that file and the shipped card's comparison (the member's own seeds are not re-run)."""
    path = ROOT / "leaderboards" / "seeds" / f"{algo}.json"
    doc = json.loads(path.read_text())
    unknown = sorted(set(others) - set(doc.get("compare", {})))
    if unknown:
        raise SystemExit(f"error: {algo}'s seeds file compares {', '.join(doc.get('compare', {}))}, not {unknown[0]}")
    multi = list(doc["compare"][others[0]])
    for other in others:
        doc["compare"][other] = compare(other, multi)
    atomic_write_bytes(path, (json.dumps(doc, indent=1, sort_keys=True) + "\n").encode())
    card_path = ROOT / "zoo" / "pretrained" / f"{algo}.json"
    card = json.loads(card_path.read_text())
    card["multi_av_comparison"] = {"table": comparison_table(doc, multi).splitlines(), **doc["compare"]}
    atomic_write_bytes(card_path, (json.dumps(card, indent=1, sort_keys=True) + "\n").encode())
    print(f"{algo}: comparison with {', '.join(others)} updated in {path.name} and {card_path.name}")


def comparison_table(doc: dict, multi: list[str]) -> str:
    """Markdown: per multi-AV suite, the member's per-AV success / crash and per-road AV-AV crash
    rates as mean (min-max) over seeds, and each compared member's (one shipped seed)."""
    import numpy as np

    rows = [
        "| decider | suite | seeds | success / AV | crash / AV | AV-AV crash / road | all succeed / road |",
        "|---|---|---|---|---|---|---|",
    ]
    keys = ("success_rate", "crash_rate", "av_av_crash_rate", "all_succeed_rate")
    for name in multi:
        vals = {k: np.array([e["suites"][name][k] for e in doc["seeds"]]) for k in keys}
        cells = " | ".join(f"{v.mean():.3f} ({v.min():.3f}-{v.max():.3f})" for v in vals.values())
        rows.append(f"| {doc['member']} | {name} | {len(doc['seeds'])} | {cells} |")
        for other, got in doc.get("compare", {}).items():
            rows.append(f"| {other} | {name} | shipped | " + " | ".join(f"{got[name][k]:.3f}" for k in keys) + " |")
    return "\n".join(rows)


if __name__ == "__main__":
    main()
