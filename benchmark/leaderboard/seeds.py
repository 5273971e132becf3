"""Every training seed of a learned member, evaluated; the seed to ship (``overtakezoo seeds``).

Each run directory is an ``overtakezoo train`` output (``<algo>.pt`` + ``<algo>.json``, and from newer
trainers ``<algo>.npz``). Every seed is run on the training splits of the suites it trained on
(``train_suite``, default ``core-train``, what the single-agent members train on) and on the core
suites (or the ones given); the outcome counts and CIs go to ``<leaderboards>/seeds/<MEMBER>.json``,
which the headline (:mod:`.headline`, :func:`~.headline.load_seeds`) reads to report the member as the
mean and spread over seeds. With ``ship`` the selected seed is exported
(:func:`overtakezoo.zoo.train.export.export`) into ``zoo/pretrained/<MEMBER>.npz`` + ``.json``.

A multi-AV suite (``duel``, ``platoon``, ``mixed-traffic`` and their training splits) is run with
every AV driven by the seed (self-play, :func:`~overtakezoo.benchmark.results.multi_metrics.joint_rates`);
its rates are per AV, with the joint ones beside them (every AV of a road succeeds, a crash between
two AVs). ``compare`` runs the named zoo members (their shipped weights) on the same multi-AV suites,
for the member's card.

Selection rule (fixed before any seed was evaluated): the median seed by mean success rate over the
*training* splits (ties: lower mean crash rate there, then the lower seed). The test suites never
enter the choice.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.results.multi_metrics import run_joint_rates
from overtakezoo.benchmark.suite_groups import CORE, load_training
from overtakezoo.envs.io import atomic_write_bytes
from overtakezoo.envs.suites import Suite, load_suite

TRAIN_SUITE = "core-train"
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
    """A seeds-file entry from a single-AV results summary (outcome counts, rates and their CIs)."""
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


def multi_counts(suite, decider, **on) -> dict:
    """Per-AV and joint outcomes of ``decider`` driving every AV of the whole multi-AV ``suite``."""
    c = run_joint_rates(suite, decider, **on)["counts"]
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


def evaluate(suite, decider, **on) -> dict:
    """The counts of one suite: the runner's summary, or per-AV rates on a multi-AV suite (``on``: the
    runner's ``device`` / ``backend`` keywords)."""
    from overtakezoo.benchmark.run.runner import run_suite

    if suite.scenarios().num_avs > 1:
        return multi_counts(suite, decider, **on)
    return counts(run_suite(suite, decider, progress=False, **on).summary)


def evaluate_run(algo: str, run: Path, suites: dict[str, Suite]) -> dict[str, Any]:
    """One run (training seed) on every suite of ``suites`` (by the name the seeds file gives it): its
    seeds-file entry. The run's ``seed-eval.json`` caches its evaluations while weights, deployment
    and suites match."""
    from overtakezoo.benchmark.run.policy import load_policy
    from overtakezoo.zoo.train.export import trained_sha256

    card_path = run / f"{algo}.json"
    try:
        card = json.loads(card_path.read_text())
    except (OSError, ValueError) as exc:
        raise UserError(f"{run}: no readable model card {card_path.name} ({type(exc).__name__})") from None
    weights_sha = trained_sha256(card)  # the torch file's: the same before and after an export
    entry = {
        "seed": card["seed"],
        "run": run.name,
        "weights_sha256": weights_sha,
        "steps": card.get("steps", card.get("training", {}).get("gradient_steps")),
        "suites": {},
    }
    cache_path = run / "seed-eval.json"
    cache = json.loads(cache_path.read_text()) if cache_path.is_file() else {}
    # how the card deploys the network (`overtakezoo decision-rate`): rate and OVERTAKE threshold
    deployed = {k: card.get(k) for k in ("decide_every", "overtake_offset")}
    if cache.get("deployed") != deployed:
        cache = {}
    for name, suite in suites.items():
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
    return entry


def store_weights(algo: str, run: Path, seed: int, root: Path) -> dict[str, str]:
    """Copy a run's weights (exported to numpy when a torch trainer wrote them) with their model card
    to ``<root>/seeds/weights/<algo>-seed<seed>.npz`` + ``.json``; the seeds entry's ``weights``."""
    import hashlib
    import tempfile

    from overtakezoo.benchmark.leaderboard.seed_verify import weights_rel

    rel = weights_rel(algo, seed)
    npz = root / rel
    npz.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=npz.parent) as tmp:
        src = run
        if (run / f"{algo}.pt").is_file():
            from overtakezoo.zoo.train.export import export

            export(run, tmp, algo)
            src = Path(tmp)
        files = {npz: (src / f"{algo}.npz").read_bytes(), npz.with_suffix(".json"): (src / f"{algo}.json").read_bytes()}
    for path, content in files.items():
        atomic_write_bytes(path, content)
    sha = {p: hashlib.sha256(c).hexdigest() for p, c in files.items()}
    return {"file": rel, "npz_sha256": sha[npz], "card_sha256": sha[npz.with_suffix(".json")]}


def export_shipped(algo: str, out: Path, pretrained: str | Path | None = None) -> int:
    """Write the zoo's shipped ``algo`` (weights + card) into the new run directory ``out``, as
    `overtakezoo train --out` would have: so the shipped seed runs beside retrained ones through
    `decision-rate` and `seeds` (retraining the seeds whose weights were never kept). Returns its seed."""
    from overtakezoo import zoo

    learned = zoo.names("learned")
    if algo not in learned:
        raise UserError(f"{algo!r} is not a learned zoo member (one of {', '.join(learned)})")
    src = _pretrained(pretrained)
    try:
        card = json.loads((src / f"{algo}.json").read_text())
        card["seed"]
    except (OSError, ValueError, KeyError) as exc:
        raise UserError(f"{src / algo}.json: no readable model card naming its seed ({type(exc).__name__})") from None
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise UserError(f"{out} exists and is not an empty directory; give a new run directory")
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out / f"{algo}.npz", (src / f"{algo}.npz").read_bytes())
    atomic_write_bytes(out / f"{algo}.json", (src / f"{algo}.json").read_bytes())
    return card["seed"]


def choose(seeds: list[dict[str, Any]], train_splits: list[str]) -> dict[str, Any]:
    """The seed to ship by the selection rule: the median by mean training-split success."""

    def train_mean(e: dict, rate: str) -> float:
        return sum(e["suites"][n][rate] for n in train_splits) / len(train_splits)

    order = sorted(seeds, key=lambda e: (train_mean(e, "success_rate"), -train_mean(e, "crash_rate"), -e["seed"]))
    return order[(len(order) - 1) // 2]


def seeds_path(root: str | Path, algo: str) -> Path:
    """``<leaderboards>/seeds/<MEMBER>.json``."""
    return Path(root) / "seeds" / f"{algo}.json"


def _json_bytes(doc: dict) -> bytes:
    return (json.dumps(doc, indent=1, sort_keys=True) + "\n").encode()


def run_seeds(
    algo: str,
    runs: list[Path],
    root: str | Path,
    suites: list[str] | None = None,
    train_suite: str = TRAIN_SUITE,
    compare_with: list[str] | None = None,
    ship: bool = False,
    write: bool = True,
    pretrained: str | Path | None = None,
) -> dict[str, Any] | None:
    """Evaluate every run of ``algo``, write its seeds file under ``root`` (unless ``write`` is
    false: then only each run's cache is filled) and, with ``ship``, publish the chosen seed into
    ``pretrained`` (default ``zoo/pretrained``). Returns the seeds file's document (None without
    ``write``)."""
    suites = list(suites or CORE)
    train = load_training(train_suite)  # (a split given by path is known by its name from here on)
    train_splits = [s.name for s in train]
    todo = {s.name: s for s in train}
    for name in suites:
        todo.setdefault(name, load_suite(name))
    seeds = [evaluate_run(algo, run, todo) for run in runs]
    if not write:
        return None
    for entry, run in zip(seeds, runs, strict=True):  # every seed's weights, so verify can re-run it
        entry["weights"] = store_weights(algo, run, entry["seed"], Path(root))
    chosen = choose(seeds, train_splits)
    doc = {
        "member": algo,
        "selection_rule": rule(train_suite),
        "shipped_seed": chosen["seed"],
        "train_suite": train_suite,
        "seeds": sorted(seeds, key=lambda e: e["seed"]),
    }
    multi = [n for n in suites if todo[n].scenarios().num_avs > 1]
    if compare_with and multi:
        doc["compare"] = {other: compare(other, multi) for other in compare_with}
    if multi:
        print(comparison_table(doc, multi))
    atomic_write_bytes(seeds_path(root, algo), _json_bytes(doc))
    print(f"{algo}: shipped seed {chosen['seed']} ({chosen['run']})")
    if ship:
        run = next(r for r in runs if r.name == chosen["run"])
        card = publish(algo, run, doc, chosen, multi, _pretrained(pretrained))
        print(f"{algo}: published {run.name} as {card.with_suffix('.npz')} + {card.name}")
    return doc


def _pretrained(pretrained: str | Path | None) -> Path:
    if pretrained is not None:
        return Path(pretrained)
    from overtakezoo.zoo.members.learned import PRETRAINED

    return PRETRAINED


def publish(algo: str, run: Path, doc: dict, chosen: dict, multi: list[str], dest: Path) -> Path:
    """Export the chosen run into ``dest`` with the selection in its card; returns the card's path."""
    note = (
        f"Seed {chosen['seed']} of {len(doc['seeds'])} training seeds "
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
    if (run / f"{algo}.pt").is_file():  # a torch trainer's output: export it to numpy
        from overtakezoo.zoo.train.export import export

        return export(run, dest, algo, updates)
    # bc / cql write their .npz directly: publish it as it is, the card completed
    shutil.copyfile(run / f"{algo}.npz", dest / f"{algo}.npz")
    card = dest / f"{algo}.json"
    atomic_write_bytes(card, _json_bytes({**json.loads((run / f"{algo}.json").read_text()), **updates}))
    return card


def compare(other: str, multi: list[str]) -> dict:
    """The zoo member ``other`` (its shipped weights) in self-play on each multi-AV suite."""
    from overtakezoo.benchmark.run.policy import load_policy

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


def compare_only(algo: str, others: list[str], root: str | Path, pretrained: str | Path | None = None) -> None:
    """Re-run the compared members ``others`` on the multi-AV suites of ``algo``'s seeds file and
    update that file and the shipped card's comparison (the member's own seeds are not re-run)."""
    path = seeds_path(root, algo)
    if not path.is_file():
        raise UserError(f"no seeds file {path}: run `overtakezoo seeds {algo} RUN_DIR...` first")
    doc = json.loads(path.read_text())
    unknown = sorted(set(others) - set(doc.get("compare", {})))
    if unknown:
        raise UserError(f"{algo}'s seeds file compares {', '.join(doc.get('compare', {}))}, not {unknown[0]}")
    multi = list(doc["compare"][others[0]])
    for other in others:
        doc["compare"][other] = compare(other, multi)
    atomic_write_bytes(path, _json_bytes(doc))
    card_path = _pretrained(pretrained) / f"{algo}.json"
    card = json.loads(card_path.read_text())
    card["multi_av_comparison"] = {"table": comparison_table(doc, multi).splitlines(), **doc["compare"]}
    atomic_write_bytes(card_path, _json_bytes(card))
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
