"""The OvertakeZoo headline: one score per decider over the ``core`` suites, with a CI, and each
decider's gap to the oracle per suite. Pure functions of outcome counts (data in, Markdown out).

Score. Per suite, ``success rate - K * crash rate``; the score is the mean over the core suites,
each suite weighted equally. Never overtaking (every scenario a timeout) scores 0; a decider scores
above 0 only where it succeeds more than K times as often as it crashes. K = 2: a crash counts twice
as much as a success, so an overtake is worth trying only when it succeeds in more than 2 of 3 tries
(a crash is the failure that matters; a timeout is safe). Averaging over nine suites means a decider
perfect on ``table1`` that fails elsewhere cannot top the board.

CI. A seeded percentile bootstrap: every suite's outcomes are resampled (a multinomial draw of
success / crash / other with the measured shares, which is resampling the scenarios with
replacement); for learned deciders with several training seeds the seeds are resampled too and the
score is their mean (rliable's stratified bootstrap over runs and tasks).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.leaderboard.seed_verify import sources
from overtakezoo.benchmark.leaderboard.untrusted import md
from overtakezoo.benchmark.suite_groups import CORE
from overtakezoo.envs import safe_json

K = 2.0  # crash weight in the score
SAMPLES = 2000
SEED = 20240101


@dataclass(frozen=True)
class Counts:
    """Outcome counts of one decider (one training seed) on one suite."""

    success: int
    crash: int
    n: int

    @property
    def score(self) -> float:
        return (self.success - K * self.crash) / self.n


def counts_from_summary(summary: dict[str, Any]) -> Counts:
    """From a results summary (``success_rate`` / ``crash_rate`` with ``k`` and ``n``)."""
    s, c = summary["success_rate"], summary["crash_rate"]
    return Counts(int(s["k"]), int(c["k"]), int(s["n"]))


def score(
    runs: dict[str, list[Counts]], suites: tuple[str, ...] = CORE, samples: int = SAMPLES, seed: Any = SEED
) -> dict[str, Any]:
    """Score of one decider. ``runs[suite]`` holds one Counts per training seed (one for a
    deterministic decider); every seed must cover every suite. Returns value, lo, hi, seeds."""
    missing = [s for s in suites if not runs.get(s)]
    if missing:
        return {"value": None, "lo": None, "hi": None, "seeds": 0, "missing": missing}
    seeds = {len(runs[s]) for s in suites}
    if len(seeds) != 1:
        raise ValueError(f"every suite needs the same number of seeds, got {sorted(seeds)}")
    m = seeds.pop()
    # value: mean over seeds of the mean over suites
    value = float(np.mean([[runs[s][j].score for s in suites] for j in range(m)]))
    rng = np.random.default_rng(seed)
    pick = rng.integers(0, m, size=(samples, m)) if m > 1 else np.zeros((samples, 1), int)
    total = np.zeros(samples)
    for s in suites:
        per_seed = np.empty((samples, m))
        for j, c in enumerate(runs[s]):
            p = np.array([c.success, c.crash, c.n - c.success - c.crash], float) / c.n
            draw = rng.multinomial(c.n, p, size=samples)
            per_seed[:, j] = (draw[:, 0] - K * draw[:, 1]) / c.n
        total += np.take_along_axis(per_seed, pick, axis=1).mean(axis=1)
    boot = total / len(suites)
    lo, hi = np.percentile(boot, [2.5, 97.5])
    return {"value": value, "lo": float(lo), "hi": float(hi), "seeds": m, "missing": []}


def mean_over_seeds(counts: list[Counts], key: str, samples: int = SAMPLES, seed: Any = SEED) -> dict[str, Any]:
    """Mean of a rate (``success`` or ``crash``) over training seeds, with a bootstrap CI over seeds
    and scenarios; ``per_seed`` lists each seed's rate."""
    rates = np.array([getattr(c, key) / c.n for c in counts])
    rng = np.random.default_rng(seed)
    m = len(counts)
    draws = np.stack([rng.binomial(c.n, getattr(c, key) / c.n, size=samples) / c.n for c in counts], axis=1)
    pick = rng.integers(0, m, size=(samples, m))
    boot = np.take_along_axis(draws, pick, axis=1).mean(axis=1)
    lo, hi = np.percentile(boot, [2.5, 97.5])
    return {"value": float(rates.mean()), "lo": float(lo), "hi": float(hi), "per_seed": rates.tolist()}


def _pct(x: float | None) -> str:
    # (a seeds file is input: anything but a number shows as "-")
    ok = isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
    return f"{100 * x:.1f}" if ok else "-"


def render(
    table: dict[str, dict[str, list[Counts]]],
    privileged: set[str],
    oracle: str = "oracle",
    suites: tuple[str, ...] = CORE,
    safety: dict[str, str] | None = None,
) -> str:
    """The headline section (Markdown): deciders ranked by score, the privileged ones apart, each
    with its gap to the oracle's success rate per suite (percentage points, mean over seeds), and
    (``safety``) the mean RSS violation rate over the suites."""
    scored = {name: score(runs, suites) for name, runs in table.items()}
    ranked = sorted(
        (n for n in table if n not in privileged),
        key=lambda n: (-(scored[n]["value"] if scored[n]["value"] is not None else -math.inf), n),
    )
    ref = table.get(oracle, {})

    def success(runs: list[Counts]) -> float:
        return float(np.mean([c.success / c.n for c in runs]))

    def gap(name: str, s: str) -> str:
        if not table[name].get(s) or not ref.get(s):
            return "-"
        return f"{100 * (success(table[name][s]) - success(ref[s])):+.1f}"

    out = [
        "## OvertakeZoo score",
        "",
        f"One number per decider over the `core` suites ({', '.join(f'`{s}`' for s in suites)}): the mean "
        f"over suites of *success rate - {K:g} x crash rate*, in %, with a 95 % bootstrap CI. Never "
        "overtaking scores 0; a decider scores above 0 only where it succeeds more than twice as often as "
        "it crashes, so an overtake is worth trying only when it works in more than 2 of 3 tries: a crash "
        "counts twice as much as a success, a timeout is safe and counts nothing. Each suite weighs the "
        "same, so a decider perfect on `table1` that fails on the others cannot top the board. Learned "
        "deciders are the mean over their training seeds, and the CI resamples the seeds as well as the "
        "scenarios (a stratified bootstrap, as rliable does). The columns after the score give the "
        "success rate minus the oracle's on each suite (percentage points; the oracle sees the future "
        "and is an upper bound, listed apart)."
        + (
            " *RSS violated* is the mean over the suites of the share of overtakes that broke the RSS "
            "opposite-direction distance (shipped rows; see *Safety and the RSS shield*)."
            if safety
            else ""
        ),
        "",
    ]
    head = [
        "rank",
        "decider",
        "seeds",
        "score [95 % CI]",
        *(["RSS violated (%)"] if safety else []),
        *[f"gap {s}" for s in suites],
    ]
    out += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]

    def row(rank: str, name: str, label: str | None = None) -> str:
        sc = scored[name]
        txt = "-" if sc["value"] is None else f"{_pct(sc['value'])} [{_pct(sc['lo'])}, {_pct(sc['hi'])}]"
        if sc["missing"]:
            txt += f" (missing: {', '.join(map(md, sc['missing']))})"
        extra = [(safety or {}).get(name, "-")] if safety else []
        return (
            "| "
            + " | ".join(
                [rank, md(label or name), str(sc["seeds"] or "-"), txt, *extra, *[gap(name, s) for s in suites]]
            )
            + " |"
        )

    out += [row(str(i), n) for i, n in enumerate(ranked, 1)]
    for n in sorted(privileged & set(table)):
        out.append(row("upper bound", n, f"{n} (privileged)"))
    out.append("")
    return "\n".join(out)


def generalization(
    table: dict[str, dict[str, list[Counts]]],
    learned: list[str],
    suites: tuple[str, ...] = CORE,
    bar: str = "fuzzy",
    safe: str = "rule-fsm",
    oracle: str = "oracle",
) -> str:
    """Markdown: every learned member on every core suite (success / crash in %, mean over its
    seeds) against the targets: success at least ``bar``'s, crash at most ``safe``'s, and no crash on
    table1; the ``bar``, ``safe`` and ``oracle`` rows for reference."""

    def rate(runs: list[Counts], key: str) -> float:
        return float(np.mean([getattr(c, key) / c.n for c in runs]))

    def cell(name: str, s: str) -> str:
        runs = table.get(name, {}).get(s)
        if not runs:
            return "-"
        su, cr = rate(runs, "success"), rate(runs, "crash")
        if name not in learned or not table.get(bar, {}).get(s) or not table.get(safe, {}).get(s):
            return f"{_pct(su)} / {_pct(cr)}"
        met = (
            su >= rate(table[bar][s], "success")
            and cr <= rate(table[safe][s], "crash")
            and (s != "table1" or cr == 0.0)
        )
        return f"{_pct(su)} / {_pct(cr)} {'met' if met else 'missed'}"

    names = [n for n in learned if n in table] + [n for n in (bar, safe, oracle) if n in table]
    out = [
        "## Off the training suite",
        "",
        f"Success / crash rate (%) of every learned member on every core suite (the mean over its "
        f"training seeds where its seeds file covers the suite), beside `{bar}`, `{safe}` and `{oracle}`. "
        f"The target for a learned member on a suite: success at least `{bar}`'s, crash rate at most "
        f"`{safe}`'s and, on `table1`, no crash at all; each learned cell says whether it is met.",
        "",
        "| decider | " + " | ".join(suites) + " |",
        "|---|" + "---|" * len(suites),
    ]
    out += [f"| {md(n)} | " + " | ".join(cell(n, s) for s in suites) + " |" for n in names]
    out.append("")
    return "\n".join(out)


# ------------------------------------------------------------------ inputs from the leaderboard
MULTI_COUNTS = ("roads", "all_succeed", "av_av_crash")  # a seeds file's per-road counts on a multi-AV suite


def load_seeds(root: Path) -> dict[str, dict[str, Any]]:
    """``seeds/<member>.json`` (written by ``overtakezoo seeds``): every training seed's outcome
    counts per suite, and the shipped seed with its selection rule."""
    out = {}
    for path in sorted((root / "seeds").glob("*.json")) if (root / "seeds").is_dir() else []:
        try:
            doc = safe_json.load_file(path, path.name)
            assert isinstance(doc["member"], str) and isinstance(doc["selection_rule"], str)
            for entry in doc["seeds"]:
                for c in entry["suites"].values():
                    assert all(isinstance(c[k], int) and not isinstance(c[k], bool) for k in ("n", "success", "crash"))
                    assert 0 <= c["success"] + c["crash"] <= c["n"] and c["n"] > 0
                    if "roads" in c:  # a multi-AV suite: per-road counts too (multi.seed_section)
                        assert all(isinstance(c[k], int) and not isinstance(c[k], bool) for k in MULTI_COUNTS)
                        assert 0 < c["roads"] and all(0 <= c[k] <= c["roads"] for k in MULTI_COUNTS[1:])
                    assert isinstance(c["suite_sha256"], str)
        except (ValueError, KeyError, TypeError, AssertionError) as exc:
            raise UserError(f"{path}: malformed seeds file ({type(exc).__name__}: {exc})") from None
        _anchored(path, doc)
        sources(doc["member"], doc)  # seeds 0..n-1, each re-runnable (seed_verify.py)
        out[doc["member"]] = doc
    return out


def _anchored(path: Path, doc: dict[str, Any]) -> None:
    """A seeds file speaks for the learned member its *file name* names, and its shipped seed is that
    member's shipped weights (the model card's sha256): a file cannot lift another member, and the
    seed whose rows :func:`build_table` can hold against the verified board is the zoo's own."""
    from overtakezoo import zoo
    from overtakezoo.zoo.members.learned import PRETRAINED

    member = path.stem
    if member not in zoo.names("learned") or doc["member"] != member:
        raise UserError(
            f"{path}: a seeds file is named after the learned member it reports (one of "
            f"{', '.join(zoo.names('learned'))}); this one says member {doc['member']!r}"
        )
    card = safe_json.load_file(PRETRAINED / f"{member}.json", f"zoo/pretrained/{member}.json")
    shipped = [e for e in doc["seeds"] if e.get("seed") == doc.get("shipped_seed")]
    zoo_sha = {card.get("trained_weights_sha256"), card.get("weights_sha256")} - {None}
    if len(shipped) != 1 or shipped[0].get("weights_sha256") not in zoo_sha:
        raise UserError(
            f"{path}: shipped seed {doc.get('shipped_seed')!r}: its weights_sha256 is not the shipped "
            f"{member}'s (zoo/pretrained/{member}.json)"
        )


def build_table(
    rows: dict[str, dict[str, dict[str, Any]]], seeds: dict[str, dict[str, Any]], hashes: dict[str, str]
) -> dict[str, dict[str, list[Counts]]]:
    """Counts per decider and suite: a member's training seeds (its seeds file must cover every scoring
    suite at the current suite hash: a member never silently falls from its seeds to one run), else
    its leaderboard row (one run). ``rows[decider][suite]`` is a results summary."""
    table: dict[str, dict[str, list[Counts]]] = {}
    for name, by_suite in rows.items():
        doc = seeds.get(name)
        for suite, summary in by_suite.items():
            per_seed = []
            if doc is not None:
                per_seed = [e["suites"].get(suite) for e in doc["seeds"]]
                missing = [
                    e["seed"]
                    for e, c in zip(doc["seeds"], per_seed, strict=True)
                    if c is None or c["suite_sha256"] != hashes.get(suite)
                ]
                if missing:
                    raise UserError(
                        f"seeds/{name}.json: seed {missing[0]} has no result on the scoring suite {suite} "
                        "at its current hash, so the headline would fall back to one run: evaluate every "
                        f"seed there (overtakezoo seeds {name} RUN_DIRS) or leave {suite} out of "
                        "the score"
                    )
                per_seed = [Counts(c["success"], c["crash"], c["n"]) for c in per_seed]
                shipped = [c for e, c in zip(doc["seeds"], per_seed, strict=True) if e["seed"] == doc["shipped_seed"]]
                if shipped and shipped[0] != counts_from_summary(summary):  # the row `--verify` re-runs
                    raise UserError(
                        f"seeds/{name}.json: shipped seed {doc['shipped_seed']} on {suite}: "
                        f"{shipped[0]} is not its leaderboard row's {counts_from_summary(summary)}"
                    )
            table.setdefault(name, {})[suite] = per_seed or [counts_from_summary(summary)]
    return table


RERUN = {"zoo": "the zoo's weights", "stored": "stored weights"}


def seed_lines(seeds: dict[str, dict[str, Any]], suite: str = "table1") -> str:
    """Markdown: every learned member's training seeds on ``suite`` (success, crash with Wilson CIs),
    their mean with a bootstrap CI over seeds and scenarios, and the shipped seed with its rule."""
    out = [
        f"### Learned deciders over their training seeds ({suite})",
        "",
        "| member | seed | success [95 % CI] | crash [95 % CI] | shipped | re-run from |",
        "|---|---|---|---|---|---|",
    ]
    rules = []
    for name, doc in sorted(seeds.items()):
        cs, hows = [], sources(name, doc)
        for e in doc["seeds"]:
            c = e["suites"].get(suite)
            if c is None:
                continue
            cs.append(Counts(c["success"], c["crash"], c["n"]))
            out.append(
                f"| {md(name)} | {md(e['seed'])} | {_pct(c['success_rate'])} % [{_pct(c['success_ci'][0])}, "
                f"{_pct(c['success_ci'][1])}] | {_pct(c['crash_rate'])} % [{_pct(c['crash_ci'][0])}, "
                f"{_pct(c['crash_ci'][1])}] | {'yes' if e['seed'] == doc['shipped_seed'] else ''} | "
                f"{RERUN[hows[e['seed']]]} |"
            )
        if cs:
            s, c = mean_over_seeds(cs, "success"), mean_over_seeds(cs, "crash")
            out.append(
                f"| **{md(name)}** | mean of {len(cs)} | {_pct(s['value'])} % [{_pct(s['lo'])}, {_pct(s['hi'])}] | "
                f"{_pct(c['value'])} % [{_pct(c['lo'])}, {_pct(c['hi'])}] | | |"
            )
        rules.append((md(name), md(doc["selection_rule"])))
    by_rule: dict[str, list[str]] = {}  # one rule for all members, or each rule with its members
    for name, text in rules:
        by_rule.setdefault(text, []).append(name)
    said = (
        next(iter(by_rule))
        if len(by_rule) == 1
        else "; ".join(f"{', '.join(names)}: {text}" for text, names in sorted(by_rule.items(), key=lambda kv: kv[1]))
    )
    out += [
        "",
        "Shipped seed: " + (said if rules else "-"),
        "",
        "Verified: `overtakezoo leaderboard --verify` re-runs every seed on its suites from the weights named in "
        "the last column (the zoo member's for the shipped seed; `seeds/weights/` for stored ones) and requires "
        "its counts exactly; a seed with neither is refused.",
        "",
    ]
    return "\n".join(out)
