"""The DAgger ablation: what each ingredient of the ``dagger`` member is worth, over 3 seeds each.

Usage: python scripts/ablation.py [--runs runs] [--seeds 0,1,2] [--variants a,b,...]
       python scripts/ablation.py --write-suites   # (re)write the wider training splits below

Every variant trains with the same budget (``zoo/hyperparams/dagger.toml``: iterations, episodes,
labels, minibatches) unless it *is* the budget's use, then every seed is run on the nine core
suites with the benchmark runner. Nothing is chosen here: the table reports test-suite results of
recipes fixed beforehand (each variant's threshold is chosen, as the member's, on training splits).

- ``dagger``: the shipped recipe (``overtakezoo train dagger --suite core-train``);
- ``oracle-states``: no aggregation of the student's states: every iteration rolls out the oracle
  alone (``beta_decay = 1``), i.e. behaviour cloning of the privileged teacher, Chen et al.'s
  first stage without the DAgger step;
- ``no-threshold``: the ``dagger`` runs with the OVERTAKE logit offset taken out again (argmax of
  the fitted classifier: the oracle's label copied as it is, the score's crash weight ignored);
- ``stack``: memory for partial observability: the student's input is the features of its last 4
  decisions (a frame stack; :class:`overtakezoo.zoo.members.learned.StackedMLPDecider`);
- ``wide``: domain randomisation (Tobin et al. 2017): trained on ``core-wide-train``, each core
  suite's own file with every scenario range widened by a quarter of its width on each side
  (speeds at most the speed limit, every bound positive), drawn with the training split's seed;
  the files are in ``scripts/ablation-suites/`` (``--write-suites`` derives them from the suite
  files alone, never from a result).

Writes ``docs/ablation.md`` and ``docs/ablation.json``: per variant the score (mean over seeds,
bootstrap CI over seeds and scenarios, as the leaderboard's) and per core suite the success and
crash rates, mean and per seed. Training runs and evaluations are cached in ``--runs``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SUITES = ROOT / "scripts" / "ablation-suites"
WIDEN = 0.25  # of a range's width, added on each side
# Scenario ranges widened (the ego's speed and the follower's stay: they are set by the speed limit).
WIDE_KEYS = (
    "lead_speed",
    "oncoming_speed",
    "lead_gap",
    "oncoming_gap",
    "oncoming_headway",
    "follower_gap",
    "reaction_time",
    "oncoming_reveal",
    "lead_boost",
)
SPEEDS = ("lead_speed", "oncoming_speed")

VARIANTS = {
    "dagger": {
        "train": "dagger",
        "what": "DAgger on core-train, OVERTAKE threshold chosen on the training splits (the shipped recipe)",
    },
    "oracle-states": {
        "train": "oracle-states",
        "set": ["beta_decay=1.0"],
        "what": "the oracle's own states only (beta = 1 every iteration: behaviour cloning of the "
        "privileged teacher, no DAgger)",
    },
    "no-threshold": {
        "from": "dagger",
        "what": "the dagger runs with the OVERTAKE offset removed (argmax of the oracle-label classifier)",
    },
    "stack": {
        "train": "stack",
        "set": ["frame_stack=4"],
        "what": "DAgger with memory: the student reads its last 4 decisions' observations (a frame stack, "
        "4 s), where sensors hide oncoming cars",
    },
    "wide": {
        "train": "wide",
        "suite": "wide",
        "what": "DAgger on core-wide-train: every core suite's scenario ranges widened by 25 % of their "
        "width on each side (domain randomisation)",
    },
}


def write_suites() -> list[Path]:
    """``<suite>-wide-train.toml`` for each core suite: its own [scenario] and [sim] tables (its
    base's, if it names one, with its own over them) with the ranges in WIDE_KEYS widened, the
    training split's count and seed."""
    from overtakezoo.benchmark.suite_groups import CORE
    from overtakezoo.envs.explicit import to_toml
    from overtakezoo.envs.suites import SUITES_DIR, suite_document

    SUITES.mkdir(exist_ok=True)
    paths = []
    for name in CORE:
        base, _ = suite_document((SUITES_DIR / f"{name}.toml").read_bytes(), name)
        split, _ = suite_document((SUITES_DIR / f"{name}-train.toml").read_bytes(), f"{name}-train")
        sc = dict(base["scenario"])
        for key in WIDE_KEYS:
            if isinstance(sc.get(key), list) and sc[key][1] > sc[key][0]:
                lo, hi = sc[key]
                pad = WIDEN * (hi - lo)
                lo, hi = max(lo - pad, lo / 2), hi + pad
                if key in SPEEDS:
                    hi = min(hi, sc["speed_limit"])
                sc[key] = [round(lo, 6), round(hi, 6)]
        header = (
            f"{name}'s own distribution with every range in {', '.join(WIDE_KEYS)} widened by "
            f"{int(WIDEN * 100)} % of its width on each side\n"
            f"(speeds at most the speed limit, lower bounds at least half the original), drawn with "
            f"{name}-train's seed.\n"
            "Written by `python scripts/ablation.py --write-suites`; a training split for the ablation only.\n\n"
        )
        doc = {
            "name": f"{name}-wide-train",
            "version": 1,
            "description": f"{name} with wider scenario ranges (domain randomisation, training only)",
            "count": split["count"],
            "seed": split["seed"],
            "scenario": sc,
            "sim": base.get("sim", {}),
        }
        path = SUITES / f"{name}-wide-train.toml"
        path.write_bytes(to_toml(header, doc))
        paths.append(path)
    return paths


def wide_spec() -> str:
    from overtakezoo.benchmark.suite_groups import CORE

    return "+".join(str((SUITES / f"{n}-wide-train.toml").relative_to(ROOT)) for n in CORE)


def train(variant: str, runs: Path, seeds: list[int]) -> list[Path]:
    """The variant's run directories, trained where missing (``overtakezoo train dagger --seeds``)."""
    v = VARIANTS[variant]
    out = runs / v["train"]
    dirs = [out.with_name(f"{out.name}-s{s}") for s in seeds]
    todo = [s for s, d in zip(seeds, dirs, strict=True) if not (d / "dagger.json").is_file()]
    if todo:
        suite = wide_spec() if v.get("suite") == "wide" else "core-train"
        cmd = [
            str(Path(sys.executable).with_name("overtakezoo")),
            "train",
            "dagger",
            "--suite",
            suite,
            "--seeds",
            ",".join(map(str, todo)),
            "--out",
            str(out),
            "--eval-suite",
            "none",
            "--no-progress",
        ]
        for item in v.get("set", []):
            cmd += ["--set", item]
        print("+", " ".join(cmd), flush=True)
        subprocess.run(cmd, check=True, cwd=ROOT)
    return dirs


def decider(run: Path, config, remove_offset: bool):
    """The run's member as it ships, or (``remove_offset``) with its OVERTAKE offset taken out."""
    from overtakezoo.envs import OVERTAKE
    from overtakezoo.zoo.members.learned import MLPDecider, StackedMLPDecider, load_weights, read_card
    from overtakezoo.zoo.members.mlp import NumpyMLP

    card = read_card(run / "dagger.json", "dagger")
    net = load_weights(run / "dagger.npz", card, "dagger")
    if remove_offset:
        layers = list(net.layers)
        w, b = layers[-1]
        b = b.copy()
        b[OVERTAKE] -= card["training"]["overtake_logit_offset"]
        layers[-1] = (w, b)
        net = NumpyMLP(tuple(layers), net.activation, net.dueling)
    cls = StackedMLPDecider if int(card.get("frame_stack", 1)) > 1 else MLPDecider
    return cls(net, "dagger", config, card)


def evaluate(variant: str, dirs: list[Path]) -> list[dict]:
    """Per seed, per core suite: the outcome counts (cached in each run as ablation-<variant>.json)."""
    from overtakezoo.benchmark.run.runner import run_suite
    from overtakezoo.benchmark.suite_groups import CORE
    from overtakezoo.envs.suites import load_suite

    out = []
    for run in dirs:
        cache = run / f"ablation-{variant}.json"
        card = json.loads((run / "dagger.json").read_text())
        got = json.loads(cache.read_text()) if cache.is_file() else {}
        if got.get("weights_sha256") != card["weights_sha256"]:
            got = {"weights_sha256": card["weights_sha256"], "seed": card["seed"], "suites": {}}
        seed_eval = run / "seed-eval.json"  # `overtakezoo seeds`' runs of the same weights, reused
        if variant != "no-threshold" and seed_eval.is_file():
            done = json.loads(seed_eval.read_text())
            if done.get("weights_sha256") == card["weights_sha256"]:
                for name in CORE:
                    if name in done and not got["suites"].get(name):
                        got["suites"][name] = {k: done[name][k] for k in ("suite_sha256", "n", "success", "crash")}
        for name in CORE:
            suite = load_suite(name)
            if got["suites"].get(name, {}).get("suite_sha256") == suite.hash:
                continue
            s = run_suite(suite, decider(run, suite.config, variant == "no-threshold"), progress=False).summary
            got["suites"][name] = {
                "suite_sha256": suite.hash,
                "n": s["success_rate"]["n"],
                "success": s["success_rate"]["k"],
                "crash": s["crash_rate"]["k"],
            }
            print(
                f"{variant} seed {card['seed']} {name}: success {s['success_rate']['value']:.3f} "
                f"crash {s['crash_rate']['value']:.3f}",
                flush=True,
            )
        cache.write_text(json.dumps(got, indent=1))
        out.append(
            {
                **got,
                "train_cpu_s": card["training"].get("cpu_time_s"),
                "offset": card["training"].get("overtake_logit_offset"),
            }
        )
    return out


def kept_variants(rerun: set[str], seeds: list[int]) -> dict[str, list[dict]]:
    """Variants not re-run this time, from the last ``docs/ablation.json``: their per-seed counts as
    they were measured, kept only while every core suite's hash is the one they were measured on."""
    from overtakezoo.benchmark.suite_groups import CORE
    from overtakezoo.envs.suites import load_suite

    path = ROOT / "docs" / "ablation.json"
    if not path.is_file():
        return {}
    hashes = {n: load_suite(n).hash for n in CORE}
    kept = {}
    for name, d in json.loads(path.read_text()).get("variants", {}).items():
        runs = d.get("runs") or []
        if name in rerun or name not in VARIANTS or [r["seed"] for r in runs] != seeds:
            continue
        if all(r["suites"].get(n, {}).get("suite_sha256") == h for r in runs for n, h in hashes.items()):
            kept[name] = [
                {**r, "train_cpu_s": c, "offset": o, "command": d.get("command")}
                for r, c, o in zip(runs, d["train_cpu_s"], d["offsets"], strict=False)
            ]
    return kept


def report(results: dict[str, list[dict]], command: str) -> tuple[str, dict]:
    from overtakezoo.benchmark.leaderboard.headline import Counts, mean_over_seeds, score
    from overtakezoo.benchmark.suite_groups import CORE

    doc = {"command": command, "variants": {}}
    head = [
        "| variant | seeds | score [95 % CI] | per-seed score | " + " | ".join(CORE) + " |",
        "|---|---|---|---|" + "---|" * len(CORE),
    ]
    for variant, seeds in results.items():
        runs = {
            n: [Counts(s["suites"][n]["success"], s["suites"][n]["crash"], s["suites"][n]["n"]) for s in seeds]
            for n in CORE
        }
        sc = score(runs)
        per_seed = [float(np.mean([runs[n][j].score for n in CORE])) for j in range(len(seeds))]
        cells = {
            n: {"success": mean_over_seeds(runs[n], "success"), "crash": mean_over_seeds(runs[n], "crash")}
            for n in CORE
        }
        doc["variants"][variant] = {
            "what": VARIANTS[variant]["what"],
            "score": sc,
            "per_seed_score": per_seed,
            "seeds": [s["seed"] for s in seeds],
            "offsets": [s["offset"] for s in seeds],
            "train_cpu_s": [s["train_cpu_s"] for s in seeds],
            "suites": cells,
            "command": seeds[0].get("command", command),
            "runs": [{k: s.get(k) for k in ("seed", "weights_sha256", "suites")} for s in seeds],
        }
        head.append(
            f"| {variant} | {len(seeds)} | {100 * sc['value']:.1f} [{100 * sc['lo']:.1f}, "
            f"{100 * sc['hi']:.1f}] | {', '.join(f'{100 * x:.1f}' for x in per_seed)} | "
            + " | ".join(
                f"{100 * cells[n]['success']['value']:.1f} / {100 * cells[n]['crash']['value']:.1f}" for n in CORE
            )
            + " |"
        )
    seeds_rows = [
        "| variant | suite | " + " | ".join(f"seed {s}" for s in doc["variants"][next(iter(results))]["seeds"]) + " |",
        "|---|---|" + "---|" * len(next(iter(results.values()))),
    ]
    for variant, d in doc["variants"].items():
        for n in CORE:
            seeds_rows.append(
                f"| {variant} | {n} | "
                + " | ".join(
                    f"{100 * s:.1f} / {100 * c:.1f}"
                    for s, c in zip(
                        d["suites"][n]["success"]["per_seed"], d["suites"][n]["crash"]["per_seed"], strict=False
                    )
                )
                + " |"
            )
    md = "\n".join(
        [
            "# DAgger ablation",
            "",
            "<!-- generated by scripts/ablation.py; do not edit -->",
            "",
            f"Made by `{command}` (2-core AMD EPYC, shared)"
            + "".join(
                f"; `{k}` kept from `{d['command']}`" for k, d in doc["variants"].items() if d["command"] != command
            )
            + ". Each variant: 3 training seeds, the same training "
            "budget (`zoo/hyperparams/dagger.toml`), run on the whole of every core suite; the score is the "
            "leaderboard's (mean over suites of success - 2 x crash, %, mean over seeds, 95 % bootstrap CI over seeds "
            "and scenarios). Cells: success / crash (%), mean over seeds. Nothing was chosen from these numbers.",
            "",
            *(f"- `{k}`: {v['what']}" for k, v in doc["variants"].items()),
            "",
            *(
                [
                    "Not in this table (defined in the script, not run here): "
                    + "; ".join(f"`{k}` ({v['what']})" for k, v in VARIANTS.items() if k not in results),
                    "",
                ]
                if set(VARIANTS) - set(results)
                else []
            ),
            *head,
            "",
            "Chosen OVERTAKE offsets (on training splits) and training CPU seconds per seed: "
            + "; ".join(f"{k}: offsets {d['offsets']}, {d['train_cpu_s']} s" for k, d in doc["variants"].items()),
            "",
            "## Per seed (success / crash, %)",
            "",
            *seeds_rows,
            "",
        ]
    )
    return md, doc


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=Path, default=ROOT / "runs")  # runs/dagger-s0 ...: the member's own runs
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--write-suites", action="store_true")
    args = ap.parse_args()
    if args.write_suites:
        for p in write_suites():
            print(f"wrote {p.relative_to(ROOT)}")
        return
    seeds = [int(s) for s in args.seeds.split(",")]
    variants = args.variants.split(",")
    unknown = sorted(set(variants) - set(VARIANTS))
    if unknown:
        sys.exit(f"error: unknown variant {unknown[0]} (known: {', '.join(VARIANTS)})")
    results = {}
    for variant in variants:
        source = VARIANTS[variant].get("from", variant)
        dirs = train(source, args.runs, seeds)
        results[variant] = evaluate(variant, dirs)
    command = "python scripts/ablation.py" + (
        "" if args.variants == ",".join(VARIANTS) else f" --variants {args.variants}"
    )
    kept = kept_variants(set(variants), seeds)
    md, doc = report({v: results.get(v) or kept[v] for v in VARIANTS if v in results or v in kept}, command)
    (ROOT / "docs" / "ablation.md").write_text(md)
    (ROOT / "docs" / "ablation.json").write_text(json.dumps(doc, indent=1) + "\n")
    print(md)


if __name__ == "__main__":
    main()
