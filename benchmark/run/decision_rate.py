"""A learned member's deployed decision rate (or OVERTAKE threshold), chosen on its training splits
and written to its run cards (``overtakezoo decision-rate``, benchmark/commands/decision_rate.py).

A member trained with each decision held ``action_repeat`` core steps (10, 1 s, for dqn, double-dqn,
ps-dqn) can be re-asked more often when deployed: its value (or policy) for a 1 s hold, read again
every k steps, is a receding horizon that reacts to a car the moment it is seen instead of up to
a second later. Whether that helps is measured, not assumed: every run (training seed) plays every
scenario of every training split of ``train_suite`` at each candidate rate (multi-AV splits with
every AV driven by the run), scored as the leaderboard scores, success - 2 x crash per road (a road
succeeds when every AV does, crashes when any does), mean over splits. The member takes the
candidate with the best mean over its runs (ties: the slower rate, nearer its training); no test
suite is read. ``decide_every`` and the whole table (``decide_every_selection``) are written into
every run's ``<MEMBER>.json``; ``overtakezoo seeds ... --ship`` then evaluates the seeds at that rate
and ships the chosen one with it.

The ``overtake_offset`` knob is chosen the same way, at the rate the cards already have: a constant
added to the member's OVERTAKE score before the argmax (a decision threshold; ties: the offset
nearest 0), written with its table as ``overtake_offset_selection``. A threshold belongs to the rate
it was chosen at: the rate is chosen with no threshold, and choosing it takes any threshold out of
the cards (choose it again after), so every run is scored alike, a shipped seed exported beside
retrained ones (``overtakezoo seeds --export-shipped``) included.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

from overtakezoo.benchmark.results.multi_metrics import run_joint_rates
from overtakezoo.benchmark.suite_groups import load_training
from overtakezoo.envs.io import atomic_write_json

# How a candidate is scored, as the selection in a card says it (cards shipped before the command
# existed name the script it replaced instead).
SCORE = "success - 2 x crash per road, mean over every scenario of every training split (overtakezoo decision-rate)"

# Each knob: how its candidates parse, the tie-break (the larger key wins among equal scores), the card's
# value that means "unchanged" (then the key is left out of the card), and how the printout names one.
KNOBS: dict[str, tuple[Callable[[str], Any], Callable[[Any], Any], Callable[[dict], Any], str]] = {
    "decide_every": (int, lambda k: k, lambda card: card.get("action_repeat", 1), "every {}"),
    "overtake_offset": (float, lambda o: -abs(o), lambda card: 0.0, "offset {:+g}"),
}


THRESHOLD_KEYS = ("overtake_offset", "overtake_offset_selection")  # chosen at a rate; dropped when it is


def split_score(suite, decider) -> float:
    """success - 2 x crash per road on the whole split, in [-2, 1]."""
    c = run_joint_rates(suite, decider)["counts"]
    return (c["all_succeed"] - 2 * c["any_crash"]) / c["roads"]


def score_task(task: tuple) -> tuple[int, object, float, list[tuple[str, float]]]:
    """One run at one candidate value of the knob on every training split: (seed, value, mean, per split).
    A task is data (paths and names) so that it can go to a worker process."""
    from overtakezoo.zoo.members.learned import MLPDecider, load_weights, read_card

    m, run, knob, k, train_suite = task
    suites = load_training(train_suite)
    card = read_card(run / f"{m}.json", m)
    deploy = {**card, knob: k}
    if knob == "decide_every":  # (the rate is chosen with no threshold: THRESHOLD_KEYS)
        deploy = {key: v for key, v in deploy.items() if key not in THRESHOLD_KEYS}
    decider = MLPDecider(load_weights(run / f"{m}.npz", card), m, suites[0].config, deploy)
    scores = [(s.name, split_score(s, decider)) for s in suites]
    return card["seed"], k, round(sum(v for _, v in scores) / len(scores), 6), scores


def _report(label: str, result: tuple) -> tuple:
    seed, k, mean_score, scores = result
    print(f"seed {seed} {label.format(k)}: {mean_score:.4f} " + " ".join(f"{n} {v:.3f}" for n, v in scores), flush=True)
    return result


def parse_candidates(knob: str, values: list[str]) -> list[Any]:
    """The distinct candidates, best tie-break first; ValueError for one that does not parse."""
    parse, tie, _, _ = KNOBS[knob]
    return sorted({parse(v) for v in values}, key=tie, reverse=True)


def choose(
    member: str, runs: list[Path], knob: str, candidates: list[Any], train_suite: str = "core-train", jobs: int = 1
) -> dict[str, Any]:
    """Score every run at every candidate, pick the best mean, write it with its table into every run's
    card (``<run>/<member>.json``); returns the selection table."""
    _, tie, unchanged, label = KNOBS[knob]
    m = member
    tasks = [(m, run, knob, k, train_suite) for run in runs for k in candidates]
    if jobs > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        # spawn: a forked copy of a process that already ran torch's thread pool can hang.
        with ProcessPoolExecutor(min(jobs, len(tasks)), mp_context=multiprocessing.get_context("spawn")) as pool:
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
        "train_suite": train_suite,
        "per_seed": per_seed,
        "mean": mean,
        "chosen": best,
        "score": SCORE,
    }
    print(
        f"{m}: mean over {len(per_seed)} seeds "
        + ", ".join(f"{label.format(k)}: {mean[str(k)]:.4f}" for k in candidates)
        + f"; chosen: {label.format(best)}"
    )
    for run in runs:
        path = run / f"{m}.json"
        card = json.loads(path.read_text())
        card.pop(knob, None)
        if knob == "decide_every":  # a threshold belongs to the rate it was chosen at
            if "overtake_offset" in card:
                print(f"{run}: its OVERTAKE threshold was chosen at another rate; taken out (choose it again)")
            for key in THRESHOLD_KEYS:
                card.pop(key, None)
        if best != unchanged(card):
            card[knob] = best
        card[f"{knob}_selection"] = selection
        atomic_write_json(path, card)
    return selection
