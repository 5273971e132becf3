"""Greedy success and crash rates of a member's runs and of the shipped member on training scenarios.

    python scripts/train_split_scores.py RUN_DIR... [--member ppo] [--suite core-train] [--from 500]

Each training suite of ``--suite`` (a mixture such as core-train) is run from scenario ``--from`` to
its end (the trainers' model selection scores the first ones; ``--from 0``: the whole split) by
every run's ``<member>.npz`` (a run of another name, such as ``overtakezoo train ppo-numpy``'s: its one
``<name>.npz``) and by the shipped ``zoo/pretrained/<member>``; the mean over the
suites is what compares a run with the shipped member on training splits only (no test suite is
read). Used for the numpy PPO on core-train (README, "PPO in numpy") and dqn's n-step returns
(README, "DQN with 3-step returns").
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from overtakezoo.benchmark.suite_groups import load_training
from overtakezoo.zoo.members.learned import MLPDecider, load_pretrained, load_weights, read_card
from overtakezoo.zoo.train.selection import decider_act, held_back_sets, outcome_rates


def scores(decider: MLPDecider, suites: list, start: int) -> list[tuple[str, float, float]]:
    rates = outcome_rates(decider_act(decider), held_back_sets(suites, start), decider.action_repeat)
    return [(suite.name, s, c) for suite, (s, c) in zip(suites, rates, strict=True)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="*", help="run directories holding <member>.npz and <member>.json")
    ap.add_argument("--member", default="ppo", help="the learned member the runs train (default: ppo)")
    ap.add_argument("--suite", default="core-train")
    ap.add_argument("--from", dest="start", type=int, default=500)
    args = ap.parse_args()
    suites = load_training(args.suite)
    m = args.member
    deciders = [(f"shipped {m}", load_pretrained(m, suites[0].config))]
    for run in args.runs:
        cards = [p for p in sorted(Path(run).glob("*.json")) if p.with_suffix(".npz").is_file()]
        name = m if (Path(run) / f"{m}.npz").is_file() or len(cards) != 1 else cards[0].stem  # (ppo-numpy's runs)
        card = read_card(Path(run) / f"{name}.json", name)
        deciders.append((run, MLPDecider(load_weights(Path(run) / f"{name}.npz", card), name, suites[0].config, card)))
    for name, decider in deciders:
        rows = scores(decider, suites, args.start)
        success, crash = np.mean([r[1] for r in rows]), np.mean([r[2] for r in rows])
        print(
            f"{name}: mean success {success:.3f}, crash {crash:.3f}, success - 2 x crash {success - 2 * crash:.3f} "
            f"over {len(rows)} suites; " + ", ".join(f"{n} {s:.3f}/{c:.3f}" for n, s, c in rows)
        )


if __name__ == "__main__":
    main()
