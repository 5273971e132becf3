"""One-off (issue 19): bring the shipped model cards (zoo/pretrained/*.json) to the one card schema,
zoo/train/card.schema.json, which the trainers now write through zoo/train/contract.py.

Only keys move or are renamed, and only values derivable from the card itself or from the shipped
.npz (its layer shapes and size, read after its sha256 is checked) are added; the weights, and so
every weights_sha256, stay as they are, and so does everything loading reads (action_repeat,
action_mask(_version), features, the architecture's activation and dueling, version).

    python scripts/normalise_cards.py [--check]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from overtakezoo.zoo.members.learned import load_weights
from overtakezoo.zoo.train.contract import card_errors
from overtakezoo.zoo.train.dqn import STEPS_UNIT as DQN_STEPS, DQNHyperparams, algorithm as dqn_algorithm
from overtakezoo.zoo.train.ppo import ALGORITHM as PPO_ALGORITHM, STEPS_UNIT as PPO_STEPS
from overtakezoo.zoo.train.typed import build

PRETRAINED = Path(__file__).resolve().parents[1] / "zoo" / "pretrained"
OLD_CATEGORICAL = "overtakezoo.zoo.categorical:CategoricalDistribution"  # zoo/categorical.py moved to zoo/train/
NEW_CATEGORICAL = "overtakezoo.zoo.train.categorical:CategoricalDistribution"


def normalised(c: dict[str, Any]) -> dict[str, Any]:
    c = json.loads(json.dumps(c))
    name = c["name"]
    versions = {}
    if "torch" in c or "torch_version" in c:  # dqn wrote `torch`, ppo `torch_version`
        versions["torch"] = c.pop("torch", None) or c.pop("torch_version")
    if "library_version" in c:  # ppo: rsl-rl-lib's version; `library` named the runner (now in `algorithm`)
        versions["rsl-rl-lib"] = c.pop("library_version")
        c.pop("library", None)
    c["versions"] = versions  # bc, cql: not recorded when they were trained
    c.pop("created", None)  # ppo only; no other card has a timestamp
    for key in ("eval_suite", "eval_suite_hash"):  # dqn's, always null: `results` names each suite with its hash
        c.pop(key, None)
    if isinstance(c.get("train_suite"), str):  # dqn: a string and a separate `train_suites`; ppo: the object
        c["train_suite"] = {"name": c["train_suite"], "suites": c.pop("train_suites")}
    training = c.setdefault("training", {})
    for key in ("core_steps", "gradient_updates", "episodes", "train_rows", "multi_av", "iterations", "selection"):
        if key in c:  # the trainer's own statistics
            training[key] = c.pop(key)
    hp = c["hyperparameters"]
    hp.setdefault("file", f"{name}.toml")  # bc, cql: trained from the shipped file (their reproduce lines)
    if "dataset" in c:
        c.setdefault("steps", training["gradient_steps"])
        c.setdefault("steps_unit", "gradient steps")
    elif "double" in hp:
        c["algorithm"] = dqn_algorithm(build(DQNHyperparams, {k: v for k, v in hp.items() if k != "file"}, name),
                                       "train_rows" in training)
        c.setdefault("steps_unit", DQN_STEPS)
    else:
        c["algorithm"], c["steps_unit"] = PPO_ALGORITHM, PPO_STEPS
        c.setdefault("action_mask", False)  # absent meant no mask
        dist = hp["actor"]["distribution_cfg"]
        if dist["class_name"] == OLD_CATEGORICAL:
            dist["class_name"] = NEW_CATEGORICAL
    arch = c["architecture"]
    for key in ("distribution", "hidden_dims", "num_modes"):  # ppo's duplicates of hyperparameters / num_actions
        arch.pop(key, None)
    output = arch.pop("output", None)  # bc, cql: logits / q-values, now `kind`
    if output is not None:
        arch["kind"] = "classifier" if output == "logits" else "q-network"
    npz = PRETRAINED / c["weights_file"]
    net = load_weights(npz, c, name)  # sha256 checked
    arch.setdefault("dueling", net.dueling)
    arch.setdefault("layers", [list(w.shape) for w, _ in net.layers])
    c["weights_format"] = "npz (overtakezoo.zoo.members.mlp, float64)"
    c.setdefault("weights_bytes", npz.stat().st_size)
    return c


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--check", action="store_true", help="only report what would change")
    args = ap.parse_args()
    bad = 0
    for path in sorted(PRETRAINED.glob("*.json")):
        before = json.loads(path.read_text())
        after = normalised(before)
        errors = card_errors(after)
        if errors:
            bad += 1
            print(f"{path.name}: {'; '.join(errors)}")
        changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
        print(f"{path.name}: {', '.join(changed) or 'unchanged'}")
        if not args.check and not errors:
            path.write_text(json.dumps(after, indent=1, sort_keys=True) + "\n")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
