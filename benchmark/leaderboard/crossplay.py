"""Cross-play: every zoo decider against every other on a multi-AV suite (``duel``, ``platoon``,
``mixed-traffic``).

Decider A drives AV 0 (the ego) and B drives every other AV of the suite's first ``scenarios``
roads (a :class:`~.pairing.Pairing`, one B object per AV: their per-row state stays apart); each
ordered pair (A, B), A = B included, is one run. On ``duel`` AV 1 drives towards -s; on
``platoon`` AVs 1 and 2 follow the ego in its direction. What is measured is written, as counts, to
``leaderboards/crossplay/<suite>.json`` (the input, like the submissions;
``overtakezoo crossplay --check`` re-runs it and requires the same bytes), and
``overtakezoo leaderboard`` turns it into ``crossplay-<suite>.md`` (matrices of joint success and
AV-AV crash rate with 95 % Wilson intervals) and ``crossplay-<suite>.png`` (heatmaps).

Privileged deciders (the oracle) are left out: they bind the whole core, and on a road shared with
another decider their simulated future would need that decider's (runner.py says why).
"""

from __future__ import annotations

import io
import json
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.leaderboard.untrusted import md, md_code, md_image, plot_text
from overtakezoo.benchmark.results.metrics import format_metric, wilson
from overtakezoo.benchmark.results.results import config_sha256
from overtakezoo.envs import SIM_VERSION, safe_json
from overtakezoo.envs.suites import Suite, load_suite

DATA = Path("crossplay")
# 500 roads per pair: the 11 x 11 matrix of the zoo's non-privileged members takes about 2-3 minutes with
# --jobs 2 on 2 cores (measured: 128 s wall, 223 s of CPU time), and a rate's 95 % interval is at most
# +-4.4 points.
DEFAULT_SCENARIOS = 500
# (key, label) of the counts kept for each pair; the matrices show the first two.
MEASURES = [
    ("all_succeed", "joint success (every AV succeeds)"),
    ("av_crash", "AV-AV crash"),
    ("any_crash", "any crash"),
    ("a_success", "A's AV succeeds"),
    ("b_success", "B's AV succeeds"),
    ("a_yielded", "A yielded"),
    ("b_yielded", "B yielded"),
]


def zoo_deciders(config: Any) -> list[str]:
    """The zoo's own members that see observations only: the rule and learned kinds of the registry
    (not the privileged oracle, nor wrappers such as the shielded ones)."""
    from overtakezoo import zoo

    return sorted(zoo.names("rule") + zoo.names("learned"))


# Pairs of an unchanged matrix `leaderboard --verify --sample K` re-runs (at least; K when more): one
# decider's row of the matrix on average, about 40 s for the three shipped matrices on 2 cores. A whole
# matrix takes minutes (2 min 22 s for duel's 144 pairs with --jobs 2, 2-core Xeon), so CI samples it.
VERIFY_PAIRS = 12
BATCH_ROADS = 8192  # roads stepped together: pairs share one batch (fewer Python steps, the same bits)


def _pairing(suite: Suite, a: str, b: str) -> Any:
    from overtakezoo import zoo
    from overtakezoo.benchmark.run.pairing import Pairing

    others = [zoo.load(b, suite.config) for _ in range(suite.num_avs - 1)]
    return Pairing([zoo.load(a, suite.config), *others], suite.config.decision_interval)


def _counts(summary: dict[str, Any]) -> dict[str, list[int]]:
    counts = {
        key: [summary["joint"][key]["k"], summary["joint"][key]["n"]] for key, _ in MEASURES if key in summary["joint"]
    }
    av, rest = summary["per_av"][0], summary["per_av"][1:]  # B's counts: summed over its AVs (per AV, not per road)
    for mine, theirs, key in (("a_success", "b_success", "success_rate"), ("a_yielded", "b_yielded", "yielded")):
        counts[mine] = [av[key]["k"], av[key]["n"]]
        counts[theirs] = [sum(r[key]["k"] for r in rest), sum(r[key]["n"] for r in rest)]
    return {key: counts[key] for key, _ in MEASURES}


def _run_group(args: tuple[str, list[tuple[str, str]], int, str | None, str | None]) -> list[dict[str, Any]]:
    """Pairs run as one batch: each pair's :class:`~.pairing.Pairing` drives its own block of roads (a
    copy of the suite's first ``scenarios``), stacked as verify stacks rows (:class:`.batching.Stacked`).
    Roads never interact and every decider sees the rows it would see alone, so each pair's counts
    are those of its own run (``tests/benchmark/test_crossplay_verify.py`` holds them to a pair run alone).
    The last two entries of ``args`` are the core's ``device`` and ``backend`` (None: the numpy core)."""
    from overtakezoo.benchmark.leaderboard.batching import Stacked
    from overtakezoo.benchmark.results.results import round_per_scenario, summary_of
    from overtakezoo.benchmark.run.runner import run_scenarios
    from overtakezoo.envs.scenarios import Scenarios

    where, pairs, scenarios, device, backend = args
    suite = load_suite(where)
    e = suite.num_avs
    base = suite.scenarios().take(np.arange(scenarios))
    stacked = Stacked([(_pairing(suite, a, b), scenarios) for a, b in pairs], e)
    batch = Scenarios.concat([base] * len(pairs))
    roads = np.tile(np.arange(scenarios), len(pairs))
    per = run_scenarios(suite, stacked, batch, roads, batch.num, safety=False, device=device, backend=backend)
    out = []
    for i, (a, b) in enumerate(pairs):
        mine = {k: v.reshape(e, -1)[:, i * scenarios : (i + 1) * scenarios].reshape(-1) for k, v in per.items()}
        out.append({"a": a, "b": b, **_counts(summary_of(round_per_scenario(mine), suite.seed, e))})
    return out


def reusable(stored: dict[str, Any] | None, suite: Suite, scenarios: int, deciders: list[dict[str, Any]]) -> set[str]:
    """The deciders whose pairs ``stored`` (an earlier matrix) already holds as a re-run would give
    them: same suite, config, simulator and scenario count, and the decider's version and weights."""
    if not stored or (
        stored["suite"].get("hash"),
        stored.get("config_sha256"),
        stored.get("sim_version"),
        stored["scenarios"],
    ) != (suite.hash, config_sha256(suite.config), SIM_VERSION, scenarios):
        return set()
    before = {d["name"]: (d["version"], d["weights_sha256"]) for d in stored["deciders"]}
    return {d["name"] for d in deciders if before.get(d["name"]) == (d["version"], d["weights_sha256"])}


def labels(suite: Suite, names: list[str]) -> list[dict[str, Any]]:
    """The ``deciders`` block of a matrix of ``names``: each zoo member's name, version and weights,
    derived from the zoo (never read from a file)."""
    from overtakezoo import zoo

    out = []
    for name in names:
        d = zoo.load(name, suite.config)
        if getattr(d, "privileged", False):
            raise UserError(f"{name}: privileged deciders cannot share a road in cross-play")
        out.append({"name": name, "version": str(d.version), "weights_sha256": d.weights_sha256})
    return out


def run_pairs(
    suite: Suite,
    wanted: list[tuple[str, str]],
    scenarios: int,
    jobs: int = 1,
    device: str | None = None,
    backend: str | None = None,
) -> dict[tuple[str, str], dict]:
    """Each ordered pair of ``wanted`` run on the suite's first ``scenarios`` roads, as ``{(a, b): pair}``:
    pairs that hold their decisions equally long share a batch of up to :data:`BATCH_ROADS` roads
    (:func:`_run_group`); ``jobs`` > 1 runs the batches in that many worker processes. ``device`` /
    ``backend`` pick the core (the runner's keywords; None: the numpy core, the same counts)."""
    where = suite.name if suite.builtin else str(suite.path)
    by_hold: dict[int, list[tuple[str, str]]] = {}
    for a, b in wanted:
        by_hold.setdefault(_pairing(suite, a, b).action_repeat, []).append((a, b))
    per_batch = max(1, BATCH_ROADS // scenarios)
    if jobs > 1:  # batches small enough that every worker gets some
        per_batch = max(1, min(per_batch, -(-len(wanted) // jobs)))
    todo = [
        (where, group[i : i + per_batch], scenarios, device, backend)
        for group in by_hold.values()
        for i in range(0, len(group), per_batch)
    ]
    if jobs > 1 and len(todo) > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        # spawn: a forked copy of a process that already ran torch's thread pool can hang.
        with ProcessPoolExecutor(min(jobs, len(todo)), mp_context=multiprocessing.get_context("spawn")) as pool:
            groups = list(pool.map(_run_group, todo))
    else:
        groups = [_run_group(t) for t in todo]
    return {(p["a"], p["b"]): p for group in groups for p in group}


def _check_scenarios(suite: Suite, scenarios: int, flag: str = "--limit") -> None:
    if suite.num_avs < 2:
        raise UserError(
            f"suite {suite.name!r} has one automated vehicle per scenario; cross-play pairs deciders "
            "on multi-AV suites (duel, platoon, mixed-traffic)"
        )
    if not 1 <= scenarios <= suite.count:
        raise UserError(f"{flag} {scenarios}: must lie in [1, {suite.count}] (the suite's scenarios)")


def measure(
    suite: Suite,
    names: list[str] | None = None,
    scenarios: int = DEFAULT_SCENARIOS,
    jobs: int = 1,
    stored: dict[str, Any] | None = None,
    device: str | None = None,
    backend: str | None = None,
) -> dict[str, Any]:
    """Run every ordered pair of ``names`` (default: :func:`zoo_deciders`) on the suite's first
    ``scenarios`` roads; returns the data document (deterministic: no timing in it). With ``stored``
    (an earlier matrix) a pair of two unchanged deciders (:func:`reusable`) is copied, not re-run:
    every pair is a deterministic function of the suite and the two deciders, on either core (``device``
    / ``backend``, :func:`run_pairs`)."""
    _check_scenarios(suite, scenarios)
    names = zoo_deciders(suite.config) if names is None else list(names)
    deciders = labels(suite, names)
    same = reusable(stored, suite, scenarios, deciders)
    old = {(p["a"], p["b"]): p for p in stored["pairs"]} if same else {}
    wanted = [(a, b) for a in names for b in names if not (a in same and b in same)]
    new = run_pairs(suite, wanted, scenarios, jobs, device=device, backend=backend)
    pairs = [new.get((a, b)) or old[(a, b)] for a in names for b in names]
    return {
        "generated_by": "overtakezoo crossplay",
        "suite": {"name": suite.name, "version": suite.version, "hash": suite.hash, "count": suite.count},
        "config_sha256": config_sha256(suite.config),
        "sim_version": SIM_VERSION,
        "scenarios": scenarios,
        "deciders": deciders,
        "pairs": pairs,
    }


def verify_matrix(
    root: str | Path,
    path: Path,
    sample: int | None,
    seed: int,
    jobs: int = 1,
    device: str | None = None,
    backend: str | None = None,
) -> str:
    """Re-derive a stored matrix as ``leaderboard --verify`` does: its suite, config and simulator
    are the current ones, its ``deciders`` block is the zoo's (derived), and every pair re-run
    (``sample`` None) or ``sample`` pairs drawn from ``seed`` give exactly the stored counts, on the
    core ``device`` / ``backend`` pick (:func:`run_pairs`). Returns the report line; :class:`UserError`
    naming the file (and the pair) otherwise."""
    from overtakezoo.envs.suites import suite_names

    rel = path.relative_to(root).as_posix() if path.is_relative_to(root) else str(path)
    doc = load(path)
    name = doc["suite"]["name"]
    if path.stem != name:
        raise UserError(f"{rel}: suite.name {name!r} filed as {path.stem!r}")
    suite = load_suite(name) if name in suite_names() else None
    stale = _stale(doc, suite)
    if stale:
        raise UserError(
            f"{rel}: measured on {'; '.join(stale)}: the board shows only what a re-run gives; "
            f"re-run `overtakezoo crossplay --suite {name}`"
        )
    _check_scenarios(suite, doc["scenarios"], f"{rel}: scenarios:")
    if doc["suite"] != {"name": suite.name, "version": suite.version, "hash": suite.hash, "count": suite.count}:
        raise UserError(f"{rel}: suite: {doc['suite']!r} is not the suite file's block (edited by hand?)")
    names = [d["name"] for d in doc["deciders"]]
    from overtakezoo import zoo

    unknown = sorted(set(names) - set(zoo.known_names()))
    if unknown:
        raise UserError(f"{rel}: deciders: {unknown[0]!r} is no zoo member (cross-play pairs the zoo's own)")
    derived = labels(suite, names)
    for got, want in zip(doc["deciders"], derived, strict=True):
        if got != want:
            raise UserError(
                f"{rel}: deciders: recorded {got!r}, derived {want!r} from the zoo (labels are derived, "
                f"never declared; re-run `overtakezoo crossplay --suite {name}` after a zoo change)"
            )
    pairs = [(p["a"], p["b"]) for p in doc["pairs"]]
    if sample is not None and sample < len(pairs):
        rng = np.random.default_rng([seed, zlib.crc32(rel.encode())])
        pairs = [pairs[i] for i in np.sort(rng.choice(len(pairs), size=sample, replace=False))]
    stored = {(p["a"], p["b"]): p for p in doc["pairs"]}
    got = run_pairs(suite, pairs, doc["scenarios"], jobs, device=device, backend=backend)
    for a, b in pairs:
        for key, label in MEASURES:
            if stored[a, b][key] != got[a, b][key]:
                raise UserError(
                    f"{rel}: pair A={a}, B={b}: {key} ({label}): recorded {stored[a, b][key]}, the re-run "
                    f"gives {got[a, b][key]} (edited by hand, or measured on other code)"
                )
    return f"verified {rel}: {len(pairs)} of {len(stored)} pairs reproduce exactly"


def to_bytes(doc: dict[str, Any]) -> bytes:
    return (json.dumps(doc, indent=1, sort_keys=True) + "\n").encode()


def data_path(root: str | Path, suite: str) -> Path:
    return Path(root) / DATA / f"{suite}.json"


def load(path: Path) -> dict[str, Any]:
    try:
        doc = safe_json.load_file(path, path.name)
        names = [d["name"] for d in doc["deciders"]]
        pairs = {(p["a"], p["b"]): p for p in doc["pairs"]}
        assert sorted(pairs) == sorted((a, b) for a in names for b in names), "pairs do not cover every ordered pair"
        for p in pairs.values():
            for key, _ in MEASURES:
                k, n = p[key]
                assert isinstance(k, int) and isinstance(n, int) and 0 <= k <= n, f"{key}: bad count {p[key]!r}"
        assert isinstance(doc["scenarios"], int) and isinstance(doc["suite"]["name"], str)
    except (OSError, ValueError, KeyError, TypeError, AssertionError) as exc:
        raise UserError(f"{path}: malformed cross-play file ({type(exc).__name__}: {exc})") from None
    return doc


def _rate(count: list[int]) -> dict[str, Any]:
    k, n = count
    lo, hi = wilson(k, n)
    return {"value": k / n if n else None, "lo": lo, "hi": hi}


def _stale(doc: dict[str, Any], suite: Suite | None) -> list[str]:
    if suite is None:
        return [f"suite {doc['suite']['name']!r} is not built in (any more)"]
    out = []
    if doc["suite"]["hash"] != suite.hash:
        out.append(f"suite file {doc['suite']['hash'][:12]} (now {suite.hash[:12]})")
    if doc["config_sha256"] != config_sha256(suite.config):
        out.append(f"environment config {doc['config_sha256'][:12]}")
    if doc["sim_version"] != SIM_VERSION:
        out.append(f"simulator v{doc['sim_version']} (now v{SIM_VERSION})")
    return out


def markdown(doc: dict[str, Any], stale: list[str]) -> str:
    # Everything from the data file is input: names, versions and hashes are escaped (untrusted.py).
    name, n, raw = md(doc["suite"]["name"]), doc["scenarios"], doc["suite"]["name"]
    names = [d["name"] for d in doc["deciders"]]
    pairs = {(p["a"], p["b"]): p for p in doc["pairs"]}
    out = [
        f"# Cross-play: {name}",
        "",
        "<!-- generated by `overtakezoo leaderboard` from crossplay/"
        f"{name}.json (measured by `overtakezoo crossplay --suite {name}`); do not edit -->",
        "",
        f"Every zoo decider against every other on the first {n} of the {md(doc['suite']['count'])} {md_code(raw)} "
        f"scenarios (suite v{md(doc['suite']['version'])}, sha256 {md_code(str(doc['suite']['hash'])[:12])}), "
        f"{len(names)} x "
        f"{len(names)} ordered pairs ({md_code(f'overtakezoo crossplay --suite {raw} --jobs 2')}; at the default "
        f"{DEFAULT_SCENARIOS} scenarios per pair an 11 x 11 matrix took 128 s wall and 223 s of CPU time on 2 cores, "
        "measured on duel; the time grows with the square of the number of deciders). Row A drives AV 0, the ego; "
        "column B drives every other AV "
        "(AV 1 on duel, towards -s, and on mixed-traffic; AVs 1 and 2 on platoon, behind the ego), one B per AV; the "
        "diagonal is self-play on the same roads. Rates per road with 95 % Wilson intervals. The oracle is "
        "left out: it is privileged (it simulates the future of its rows, which on a shared road would need "
        "the other decider's).",
        "",
    ]
    if stale:
        out += [
            f"**Stale**: measured on {'; '.join(map(md, stale))}: re-run "
            f"{md_code(f'overtakezoo crossplay --suite {raw}')}.",
            "",
        ]
    versions = ", ".join(
        f"{md(d['name'])} v{md(d['version'])}"
        + (f" {md_code(str(d['weights_sha256'])[:10])}" if d["weights_sha256"] else "")
        for d in doc["deciders"]
    )
    out += [f"Deciders: {versions}.", ""]
    for key, label in MEASURES[:2]:
        out += [
            f"## {label}",
            "",
            "| A (AV 0) \\ B (the other AVs) | " + " | ".join(map(md, names)) + " |",
            "|" + "---|" * (len(names) + 1),
        ]
        for a in names:
            cells = [format_metric(_rate(pairs[(a, b)][key]), "rate", "%") for b in names]
            out.append(f"| **{md(a)}** | " + " | ".join(cells) + " |")
        out.append("")
    out += [
        "## Per decider",
        "",
        "Each decider's mean over its partners (both seats, self-play included): joint success, AV-AV crash, "
        "and how often its own AV yielded (aborted or never pulled out while the other AV passed first). "
        "Sorted by joint success.",
        "",
        "| decider | joint success | AV-AV crash | yielded |",
        "|---|---|---|---|",
    ]
    summary = []
    for d in names:
        mine = [pairs[(d, b)] for b in names] + [pairs[(a, d)] for a in names]
        mean = lambda key, rows: float(np.mean([r[key][0] / r[key][1] for r in rows]))  # noqa: E731
        yielded = float(
            np.mean(
                [pairs[(d, b)]["a_yielded"][0] / pairs[(d, b)]["a_yielded"][1] for b in names]
                + [pairs[(a, d)]["b_yielded"][0] / pairs[(a, d)]["b_yielded"][1] for a in names]
            )
        )
        summary.append((-mean("all_succeed", mine), mean("av_crash", mine), d, yielded))
    for neg_ok, crash, d, yielded in sorted(summary):
        out.append(f"| {md(d)} | {-neg_ok * 100:.1f} % | {crash * 100:.1f} % | {yielded * 100:.1f} % |")
    out += against_reference(names, pairs)
    out += ["", md_image("cross-play heatmaps", f"crossplay-{raw}.png"), ""]
    return "\n".join(out)


REFERENCE = "fuzzy"  # the hand-written decider a learned multi-AV member has to match, in every seat


def against_reference(names: list[str], pairs: dict[tuple[str, str], dict[str, Any]]) -> list[str]:
    """Each decider against ``REFERENCE`` put in the same place: for every partner B (itself and the
    reference included), its joint success as the ego beside B against the reference's there, and as
    B's partner against the reference's there; how many of those 2N it matches and the largest miss."""
    if REFERENCE not in names:
        return []
    rate = lambda a, b: pairs[(a, b)]["all_succeed"][0] / pairs[(a, b)]["all_succeed"][1]  # noqa: E731
    out = [
        "",
        f"## Against {md(REFERENCE)}, place by place",
        "",
        f"For each decider D and each partner B: D's joint success as the ego beside B against {md(REFERENCE)}'s "
        f"as the ego beside B, and D's as B's partner (column D of row B) against {md(REFERENCE)}'s there; "
        "2 x the number of deciders places. A decider that leads only on average can still fall short in "
        "some places: the largest shortfall is named.",
        "",
        f"| decider | places at least {md(REFERENCE)}'s | largest shortfall |",
        "|---|---|---|",
    ]
    for d in names:
        if d == REFERENCE:
            continue
        places = [
            (rate(d, b) - rate(REFERENCE, b), f"ego beside {md(b)}", rate(d, b), rate(REFERENCE, b)) for b in names
        ]
        places += [
            (rate(b, d) - rate(b, REFERENCE), f"partner of {md(b)}", rate(b, d), rate(b, REFERENCE)) for b in names
        ]
        ok = sum(gap >= 0 for gap, *_ in places)
        gap, where, mine, ref = min(places, key=lambda p: p[0])
        worst = f"{where}: {mine * 100:.1f} % against {ref * 100:.1f} %" if gap < 0 else "none"
        out.append(f"| {md(d)} | {ok} of {len(places)} | {worst} |")
    return out


def heatmap(doc: dict[str, Any]) -> bytes:
    """Joint success and AV-AV crash rate as two heatmaps; Agg canvas, no timestamps (as leaderboard._plot)."""
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    names = [d["name"] for d in doc["deciders"]]
    pairs = {(p["a"], p["b"]): p for p in doc["pairs"]}
    with matplotlib.rc_context({"svg.hashsalt": "overtakezoo", "font.family": "DejaVu Sans", "font.size": 8}):
        fig = Figure(figsize=(12.0, 5.4), dpi=100)
        FigureCanvasAgg(fig)
        for i, ((key, label), cmap) in enumerate(zip(MEASURES[:2], ("Greens", "Reds"), strict=True)):
            ax = fig.add_subplot(1, 2, i + 1)
            m = np.array([[100.0 * pairs[(a, b)][key][0] / pairs[(a, b)][key][1] for b in names] for a in names])
            im = ax.imshow(m, vmin=0, vmax=100, cmap=cmap)
            for r in range(len(names)):
                for c in range(len(names)):
                    ax.text(
                        c,
                        r,
                        f"{m[r, c]:.0f}",
                        ha="center",
                        va="center",
                        fontsize=7,
                        color="white" if m[r, c] > 60 else "black",
                    )
            ax.set_xticks(range(len(names)), [plot_text(x) for x in names], rotation=45, ha="right")
            ax.set_yticks(range(len(names)), [plot_text(x) for x in names])
            ax.set_xlabel("B (every other AV)")
            ax.set_ylabel("A (AV 0, the ego)")
            ax.set_title(f"{label} (%)")
            fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04)
        fig.suptitle(f"{plot_text(doc['suite']['name'])}: cross-play on {doc['scenarios']} scenarios, measured")
        fig.tight_layout()
        buf = io.BytesIO()
        fig.savefig(buf, format="png", metadata={"Software": None})
    return buf.getvalue()


def generated(root: str | Path) -> tuple[dict[str, bytes], dict[str, Any]]:
    """The generated files of every measured matrix under ``root/crossplay/``, and their index entries."""
    from overtakezoo.envs.suites import suite_names

    files: dict[str, bytes] = {}
    index: dict[str, Any] = {}
    for path in sorted((Path(root) / DATA).glob("*.json")):
        doc = load(path)
        name = doc["suite"]["name"]
        if path.stem != name:
            raise UserError(f"{path}: suite.name {name!r} filed as {path.stem!r}")
        stale = _stale(doc, load_suite(name) if name in suite_names() else None)
        files[f"crossplay-{name}.md"] = markdown(doc, stale).encode()
        files[f"crossplay-{name}.png"] = heatmap(doc)
        index[name] = {
            "table": f"crossplay-{name}.md",
            "plot": f"crossplay-{name}.png",
            "data": (DATA / path.name).as_posix(),
            "scenarios": doc["scenarios"],
            "deciders": [d["name"] for d in doc["deciders"]],
            "stale": stale,
        }
    return files, index
