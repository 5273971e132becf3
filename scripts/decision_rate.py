"""Pick a learned member's deployed decision rate (or OVERTAKE threshold) on its training splits; write it to its cards.

    python scripts/decision_rate.py MEMBER RUN_DIR... [--candidates 10,5,2,1] [--train-suite core-train]
    python scripts/decision_rate.py MEMBER RUN_DIR... --overtake-offsets=-1.5,-1,-0.5,0

A member trained with each decision held ``action_repeat`` core steps (10, 1 s, for dqn, double-dqn,
ps-dqn) can be re-asked more often when deployed: its value (or policy) for a 1 s hold, read again
every k steps, is a receding horizon that reacts to a car the moment it is seen instead of up to
a second later. Whether that helps is measured, not assumed: every run (training seed) plays every
scenario of every training split of ``--train-suite`` at each candidate rate (multi-AV splits with
every AV driven by the run), scored as the leaderboard scores, success - 2 x crash per road (a road
succeeds when every AV does, crashes when any does), mean over splits. The member takes the
candidate with the best mean over its runs (ties: the slower rate, nearer its training); no test
suite is read. ``decide_every`` and the whole table (``decide_every_selection``) are written into
every run's ``<MEMBER>.json``; ``scripts/seed_results.py ... --ship`` then evaluates the seeds at
that rate and ships the chosen one with it.

``--overtake-offsets`` chooses the other deployment knob the same way, at the rate the cards already
have: a constant added to the member's OVERTAKE score before the argmax (``overtake_offset``, a
decision threshold; ties: the offset nearest 0), written with its table as ``overtake_offset_selection``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from multi_rates import rates  # this script's folder is on sys.path

from overtakezoo.envs.io import atomic_write_json
from overtakezoo.envs.suites import load_training
from overtakezoo.zoo.members.learned import MLPDecider, load_weights, read_card


def split_score(suite, decider: MLPDecider) -> float:
    """success - 2 x crash per road on the whole split, in [-2, 1]."""
    c = rates(suite, decider, None)["counts"]
    return (c["all_succeed"] - 2 * c["any_crash"]) / c["roads"]


def score_task(task: tuple) -> tuple[int, object, float, list[tuple[str, float]]]:
    """One run at one candidate value of the knob on every training split: (seed, value, mean, per split).
    A task is data (paths and names) so that it can go to a worker process."""
    m, run, knob, k, train_suite = task
    suites = load_training(train_suite)
    card = read_card(run / f"{m}.json", m)
    decider = MLPDecider(load_weights(run / f"{m}.npz", card), m, suites[0].config, {**card, knob: k})
    scores = [(s.name, split_score(s, decider)) for s in suites]
    return card["seed"], k, round(sum(v for _, v in scores) / len(scores), 6), scores


def _report(label: str, result: tuple) -> tuple:
    seed, k, mean_score, scores = result
    print(f"seed {seed} {label.format(k)}: {mean_score:.4f} " + " ".join(f"{n} {v:.3f}" for n, v in scores), flush=True)
    return result


# Each knob: how its candidates parse, the tie-break (the larger key wins among equal scores), the card's
# value that means "unchanged" (then the key is left out of the card), and how the printout names one.
KNOBS = {
    "decide_every": (int, lambda k: k, lambda card: card.get("action_repeat", 1), "every {}"),
    "overtake_offset": (float, lambda o: -abs(o), lambda card: 0.0, "offset {:+g}"),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("member")
    ap.add_argument("runs", nargs="+", type=Path, help="the member's run directories (one per training seed)")
    ap.add_argument("--candidates", default="10,5,2,1", help="core steps between decisions to try")
    ap.add_argument(
        "--overtake-offsets",
        metavar="LIST",
        help="choose the OVERTAKE score offset among these instead (at the cards' decision rate)",
    )
    ap.add_argument("--train-suite", default="core-train", help="what the member trained on (its splits choose)")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes (one run at one candidate each; same table)")
    args = ap.parse_args()
    knob = "overtake_offset" if args.overtake_offsets else "decide_every"
    parse, tie, unchanged, label = KNOBS[knob]
    values = (args.overtake_offsets or args.candidates).split(",")
    m, candidates = args.member, sorted({parse(v) for v in values}, key=tie, reverse=True)
    tasks = [(m, run, knob, k, args.train_suite) for run in args.runs for k in candidates]
    if args.jobs > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        # spawn: a forked copy of a process that already ran torch's thread pool can hang.
        with ProcessPoolExecutor(min(args.jobs, len(tasks)), mp_context=multiprocessing.get_context("spawn")) as pool:
            done = pool.map(score_task, tasks)
            results = [_report(label, r) for r in done]
    else:
        results = [_report(label, score_task(t)) for t in tasks]
    per_seed: dict[str, dict[str, float]] = {}
    for seed, k, mean_score, _ in results:
        per_seed.setdefault(str(seed), {})[str(k)] = mean_score
    mean = {str(k): round(sum(r[str(k)] for r in per_seed.values()) / len(per_seed), 6) for k in candidates}
    best = max(candidates, key=lambda k: (mean[str(k)], tie(k)))
    selection = {
        "candidates": candidates,
        "train_suite": args.train_suite,
        "per_seed": per_seed,
        "mean": mean,
        "chosen": best,
        "score": "success - 2 x crash per road, mean over every scenario of every "
        "training split (scripts/decision_rate.py)",
    }
    print(
        f"{m}: mean over {len(per_seed)} seeds "
        + ", ".join(f"{label.format(k)}: {mean[str(k)]:.4f}" for k in candidates)
        + f"; chosen: {label.format(best)}"
    )
    for run in args.runs:
        path = run / f"{m}.json"
        card = json.loads(path.read_text())
        card.pop(knob, None)
        if best != unchanged(card):
            card[knob] = best
        card[f"{knob}_selection"] = selection
        atomic_write_json(path, card)


if __name__ == "__main__":
    main()
