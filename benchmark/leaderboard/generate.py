"""The leaderboard: submissions in, Markdown tables + a JSON index + PNG plots out, byte-identical.

Layout under the root (``leaderboards/``): ``submissions/<suite>/<name>.json`` (results files
with the policy that re-runs them, and ``submissions/artifacts/``: see submission.py; the input),
``reference/paper.json`` (the paper's reported numbers, input), and the generated files
``README.md``, ``index.json``, ``<suite>.md`` and ``<suite>.png``. Generated files are never edited by
hand; ``leaderboard --check`` fails when they differ from what the submissions give. The multi-agent
suites (``suite_groups.MULTI``) get their own tables (multi_leaderboard.py) and index section
(``multi_agent``); a cross-play matrix measured by ``overtakezoo crossplay`` (``crossplay/<suite>.json``,
an input like the submissions) becomes ``crossplay-<suite>.md`` and ``.png`` (crossplay.py).

A leaderboard pull request is hostile input (untrusted.py): regeneration replaces or removes only
the files it generated (``index.json``'s ``files``), refuses a symlink or non-regular file under the
root, and every string from input is escaped on the pages and plots.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from overtakezoo import zoo
from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.leaderboard import crossplay, drivers, fresh, headline, paper_table, safety_board
from overtakezoo.benchmark.leaderboard import multi as multi_leaderboard
from overtakezoo.benchmark.leaderboard.guide import GUIDE, GUIDE_HEADING, SECURITY
from overtakezoo.benchmark.leaderboard.plots import rate_plot
from overtakezoo.benchmark.leaderboard.rows import Row, board_reasons, load_submissions
from overtakezoo.benchmark.leaderboard.untrusted import (
    check_target,
    check_tree,
    md,
    md_code,
    md_image,
    md_link,
    plain_name,
)
from overtakezoo.benchmark.results.metrics import TABLE, crash_same_scenarios, format_metric, render_table
from overtakezoo.benchmark.suite_groups import CORE, DRIVER_FAMILIES, MULTI, driver_suite
from overtakezoo.envs import safe_json
from overtakezoo.envs.io import atomic_write_bytes
from overtakezoo.envs.suites import load_suite, suite_names

REFERENCE = Path("reference") / "paper.json"
REFERENCE_NOTE = "reported in the paper, different simulator"
SHAPE_NOTES = Path("reference") / "table1-shape.json"  # why a Table I row's shape differs (paper_table.py)
_GENERATED_SUFFIXES = (".md", ".png", ".json")
_RANK_COLUMNS = [
    ("success_rate", "rate", "%"),
    ("crash_rate", "rate", "%"),
    ("timeout_rate", "rate", "%"),
    ("completion_time", "mean", "s"),
    ("crash_share_npc1", "rate", "%"),
    ("crash_share_npc2", "rate", "%"),
    ("aborts", "mean", ""),
    ("opposite_time", "mean", "s"),
]
LEARNED = set(zoo.names("learned"))  # the zoo's learned members (targets in the headline): the registry's
_LABELS = {k: label for k, label, _, _ in TABLE}


# ------------------------------------------------------------------ generate
def load_reference(root: Path) -> dict[str, Any] | None:
    path = root / REFERENCE
    if not path.is_file():
        return None
    try:
        ref = safe_json.load_file(path, path.name)
        assert isinstance(ref["rows"], list) and all(isinstance(r["decider"], str) for r in ref["rows"])
        assert isinstance(ref["suite"], str) and isinstance(ref["source"], str)
    except (ValueError, KeyError, TypeError, AssertionError) as exc:
        raise UserError(f"{path}: malformed reference file ({type(exc).__name__}: {exc})") from None
    return ref


def generate(root: str | Path = "leaderboards") -> dict[str, bytes]:
    """Every generated file (relative path -> bytes), computed from the submissions."""
    root = Path(root)
    check_tree(root)  # before anything under it is read: no links out, no FIFO to hang on
    subs, ref = load_submissions(root), load_reference(root)
    files: dict[str, bytes] = {}
    index: dict[str, Any] = {"generated_by": "overtakezoo leaderboard", "suites": {}}
    cross_files, cross_index = crossplay.generated(root)
    files.update(cross_files)
    multi: dict[str, Any] = {}
    live_rows: dict[str, list[Row]] = {}
    driver_rows: dict[str, dict[str, list[Row]]] = {}  # family -> population -> live rows
    driver_index: dict[str, Any] = {}  # the drivers suites' own entries (apart from the ranked suites)
    seeds = headline.load_seeds(root)
    for name in sorted(set(subs) | ({ref["suite"]} if ref else set())):
        suite = load_suite(name) if name in suite_names() else None
        rows = subs.get(name, [])
        reasons = {row.rel: board_reasons(row.results, suite) for row in rows}  # stale, or not the suite's shape
        flagged = [row for row in sorted(rows, key=_rank_key) if not reasons[row.rel] and fresh.flag(row.results)]
        out = {row.rel for row in flagged}  # (rows whose fresh draw disagrees with the public suite: fresh.py)
        live = sorted((row for row in rows if not reasons[row.rel] and row.rel not in out), key=_rank_key)
        ranked = [row for row in live if not row.privileged]
        bounds = [row for row in live if row.privileged]  # they see the future: shown apart, never ranked
        stale = [(row, reasons[row.rel]) for row in rows if reasons[row.rel]]
        population = driver_suite(name)  # (family, population) of a held-out drivers suite
        if population:
            driver_rows.setdefault(population[0], {})[population[1]] = live
        if name in MULTI or (population and DRIVER_FAMILIES[population[0]] in MULTI):
            entry = _multi_suite(name, suite, live, flagged, stale, files, cross_index.get(name), seeds)
            (driver_index if population else multi)[name] = entry
            continue
        suite_ref = ref if ref and ref["suite"] == name else None
        live_rows[name] = live
        paper = _paper_section(ranked, suite_ref, root) if suite_ref else ""
        covered = {
            m: d
            for m, d in seeds.items()
            if suite is not None
            and all(e["suites"].get(name, {}).get("suite_sha256") == suite.hash for e in d["seeds"])
        }
        if covered:  # learned members as the mean and spread over their training seeds
            paper += headline.seed_lines(covered, name) + "\n"
        files[f"{name}.md"] = _markdown(name, suite, ranked, bounds, stale, suite_ref, paper, flagged).encode()
        if live:
            files[f"{name}.png"] = rate_plot(name, ranked, bounds)
        (driver_index if population else index["suites"])[name] = {
            "version": suite.version if suite else None,
            "hash": suite.hash if suite else None,
            "count": suite.count if suite else None,
            "table": f"{name}.md",
            "plot": f"{name}.png" if live else None,
            "entries": [_entry(row) for row in ranked],
            "upper_bounds": [_entry(row) for row in bounds],
            "flagged": [{**_entry(row), "why": fresh.flag(row.results)} for row in flagged],
            "stale": [
                {"file": row.rel, "reasons": [{"field": f, "measured_on": w} for f, w in why]} for row, why in stale
            ],
            "reference": REFERENCE.as_posix() if suite_ref else None,
        }
    means = safety_board.core_means(live_rows, CORE)  # (the score page's RSS column, the shield section)
    head_md, index["headline"] = _headline(live_rows, seeds, means)
    shield_md, shield_png = safety_board.readme_section(means, CORE)
    if shield_png is not None:
        files["shield.png"] = shield_png
        head_md += "\n" + "\n".join(shield_md)
    if multi or cross_index:  # (absent until a multi-agent row or matrix exists)
        index["multi_agent"] = multi
        index["crossplay"] = cross_index
    if driver_rows:  # (absent until a row on a drivers suite exists)
        families = {
            f: drivers.family_entry(f, driver_rows[f], DRIVER_FAMILIES[f] in MULTI) for f in sorted(driver_rows)
        }
        files[drivers.TABLE] = drivers.markdown(families, driver_rows).encode()
        index["drivers"] = {
            "table": drivers.TABLE,
            "populations": drivers.DRIVERS,
            "families": families,
            "suites": driver_index,
        }
    for rel in files:  # suite names come from input (folder names, reference/paper.json)
        if not plain_name(rel):
            raise UserError(
                f"{root}: suite {rel.rsplit('.', 1)[0]!r}: not a plain file name; refusing to write {rel!r}"
            )
    # What regeneration owns (and may remove later): only these, never a file it did not write.
    index["files"] = sorted(set(files) | {"index.json", "README.md"})
    files["index.json"] = (json.dumps(index, indent=1, sort_keys=True) + "\n").encode()
    files["README.md"] = _readme(index, head_md).encode()
    return files


def _multi_suite(
    name: str,
    suite: Any,
    live: list[Row],
    flagged: list[Row],
    stale: list,
    files: dict[str, bytes],
    cross: dict[str, Any] | None,
    seeds: dict[str, Any],
) -> dict[str, Any]:
    """A multi-agent suite's table and plot (into ``files``); returns its index entry."""
    ml = multi_leaderboard
    ranked, bounds = ml.split(live)
    over_seeds = ml.seed_entries(seeds, suite, ranked, bounds) if suite is not None else {}
    files[f"{name}.md"] = ml.markdown(
        name, suite, ranked, bounds, stale, _policy_cell, cross and cross["table"], flagged, over_seeds
    ).encode()
    if live:
        files[f"{name}.png"] = ml.plot(name, ranked, bounds)
    return {
        "version": suite.version if suite else None,
        "hash": suite.hash if suite else None,
        "count": suite.count if suite else None,
        "table": f"{name}.md",
        "plot": f"{name}.png" if live else None,
        "entries": [ml.entry(row, _entry(row), bounds) for row in ranked],
        "upper_bounds": [ml.entry(row, _entry(row)) for row in bounds],
        "seeds": over_seeds,
        "flagged": [{**ml.entry(row, _entry(row)), "why": fresh.flag(row.results)} for row in flagged],
        "stale": [{"file": row.rel, "reasons": [{"field": f, "measured_on": w} for f, w in why]} for row, why in stale],
    }


def _headline(
    live_rows: dict[str, list[Row]], seeds: dict[str, Any], means: dict[str, dict[str, float]]
) -> tuple[str, dict[str, Any]]:
    """The OvertakeZoo score over the core suites (benchmark/leaderboard/headline.py), learned members as the
    mean over their training seeds (``seeds/<member>.json``) where those cover the current suites."""
    rows: dict[str, dict[str, Any]] = {}
    privileged = set()
    hashes = {}
    for suite in CORE:
        for row in live_rows.get(suite, []):
            rows.setdefault(row.name, {})[suite] = row.results.summary
            hashes[suite] = row.results.suite["hash"]
            if row.privileged:
                privileged.add(row.name)
    table = headline.build_table(rows, seeds, hashes)
    scores = {name: headline.score(runs, CORE) for name, runs in table.items()}
    learned = sorted(set(seeds) | (LEARNED & set(table)))
    safety = safety_board.safety_column(means) if any(m["rss"] == m["rss"] for m in means.values()) else None
    text = (
        headline.render(table, privileged, suites=CORE, safety=safety)
        + "\n"
        + headline.generalization(table, learned, suites=CORE)
        + "\n"
        + headline.seed_lines(seeds)
    )
    return text, {"core": list(CORE), "k": headline.K, "scores": scores}


def _paper_section(ranked: list[Row], ref: dict[str, Any], root: Path) -> str:
    """Table I beside the paper (benchmark/leaderboard/paper_table.py) for dqn and rule-fsm, when both have rows."""
    by_name = {row.name: row for row in ranked}
    dqn, fsm = by_name.get("dqn"), by_name.get("rule-fsm")
    if dqn is None or fsm is None:
        return ""
    paired = crash_same_scenarios(
        {"outcome": dqn.results.per_scenario_array("outcome")}, {"outcome": fsm.results.per_scenario_array("outcome")}
    )
    path = root / SHAPE_NOTES
    try:
        notes = safe_json.load_file(path, path.name) if path.is_file() else {}
    except ValueError as exc:
        raise UserError(f"{path}: malformed notes file ({exc})") from None
    if not isinstance(notes, dict):
        raise UserError(f"{path}: malformed notes file (expected an object of row notes)")
    return (
        "## Table I beside the paper\n\n"
        f"The paper's two columns ({REFERENCE_NOTE}) next to ours for the shipped `dqn` and `rule-fsm` "
        "(OpenPlanner only), with 95 % CIs. *Shape* compares which column is higher: the paper's RL vs "
        "OP against our dqn vs rule-fsm (above or below when our CIs do not overlap, level when they "
        "do). The crash-in-the-same-scenarios row is one paired number per pair of columns.\n\n"
        + paper_table.render(ref, dqn.results.summary, fsm.results.summary, paired, notes)
        + "\n"
    )


def _entry(row: Row) -> dict[str, Any]:
    r = row.results
    return {
        "name": row.name,
        "decider": r.decider["name"],
        "version": r.decider["version"],
        "file": row.rel,
        "policy": (r.meta.get("submission") or {}).get("policy"),
        "privileged": row.privileged,
        "overtakezoo": r.meta["package"]["version"],
        "sim_version": r.meta.get("sim_version"),
        **{k: r.summary[k]["value"] for k, _, _ in _RANK_COLUMNS},
        "fresh": fresh.summary(r),
    }


def write(root: str | Path = "leaderboards") -> list[str]:
    """Regenerate the files; removes files it generated before and no longer produces (never a
    file it did not generate). Returns changed paths."""
    root = Path(root)
    files = generate(root)
    changed = stale_files(root, files)
    for rel in changed:
        path = check_target(root, rel)  # a plain name, not a link: the write stays in the root
        if rel in files:
            atomic_write_bytes(path, files[rel])
        else:
            path.unlink()
    return changed


def stale_files(root: str | Path, files: dict[str, bytes] | None = None) -> list[str]:
    """Generated files that are missing, different, or no longer produced (among the owned ones)."""
    root = Path(root)
    files = generate(root) if files is None else files
    check_tree(root)  # (again, for files handed in): only regular files are compared or removed
    out = [rel for rel, data in files.items() if not (root / rel).is_file() or (root / rel).read_bytes() != data]
    obsolete = [rel for rel in owned_files(root, files) - set(files) if (root / rel).is_file()]
    return sorted(out + sorted(obsolete))


def owned_files(root: Path, files: dict[str, bytes]) -> set[str]:
    """The files regeneration may replace or remove: what it generates now, and what the previous
    index.json lists as generated (``files``; an index from before that list: its tables and plots).
    The index is input like the rest: only plain generated-looking names in the root count."""
    owned = set(files)
    try:
        prev = safe_json.load_file(root / "index.json")  # malformed, too large or too deep: no previous index
    except (OSError, ValueError):
        prev = {}
    if not isinstance(prev, dict):
        prev = {}
    listed = prev.get("files")
    if isinstance(listed, list):
        owned |= {n for n in listed if isinstance(n, str)}
    else:
        for section in ("suites", "multi_agent", "crossplay"):
            entries = prev.get(section)
            for entry in entries.values() if isinstance(entries, dict) else ():
                if isinstance(entry, dict):
                    owned |= {v for v in (entry.get("table"), entry.get("plot")) if isinstance(v, str)}
    return {n for n in owned if plain_name(n) and Path(n).suffix in _GENERATED_SUFFIXES}


# ------------------------------------------------------------------ rendering
def _rank_key(row: Row) -> tuple:
    s = row.results.summary
    return (-(s["success_rate"]["value"] or 0.0), s["crash_rate"]["value"] or 0.0, row.name)


def _policy_cell(row: Row) -> str:
    """What re-runs the row: a built-in (version, weights) or a stored policy file (its sha256)."""
    policy = (row.results.meta.get("submission") or {}).get("policy")
    if policy is None:
        return f"v{md(row.results.decider['version'])}"
    if "artifact" in policy:
        return f"file {md_code(policy['sha256'][:10])}"
    weights = f" {md_code(policy['weights_sha256'][:10])}" if policy["weights_sha256"] else ""
    return f"built-in v{md(policy['version'])}{weights}"


def _rows_table(rows: list[Row], ranked: bool) -> list[str]:
    head = (["rank"] if ranked else []) + [
        "name",
        "policy",
        *[_LABELS[k] for k, _, _ in _RANK_COLUMNS],
        multi_leaderboard.FRESH_LABEL,
        "overtakezoo",
        "commit",
    ]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for i, row in enumerate(rows, 1):
        r = row.results
        cells = ([str(i)] if ranked else []) + [
            md_link(row.name, row.rel),
            _policy_cell(row),
            *[format_metric(r.summary[k], kind, unit) for k, kind, unit in _RANK_COLUMNS],
            fresh.cell(r),
            md(r.meta["package"]["version"]),
            md((r.meta["git_commit"] or "-")[:10]),
        ]
        out.append("| " + " | ".join(cells) + " |")
    return out


def _markdown(
    name: str,
    suite: Any,
    ranked: list[Row],
    bounds: list[Row],
    stale: list,
    ref: dict[str, Any] | None,
    paper: str = "",
    flagged: list[Row] = (),
) -> str:
    out = multi_leaderboard.page_header(name, name, suite)
    out += ["## Measured", ""]
    if ranked or bounds:
        out.append(
            "Sorted by success rate, then crash rate. Values with 95 % confidence intervals "
            "(Wilson for rates, seeded bootstrap for means). Every row re-runs with "
            "`overtakezoo leaderboard --verify`. " + multi_leaderboard.FRESH_NOTE
        )
        out.append("")
        out += _rows_table(ranked, ranked=True) if ranked else ["No ranked submissions yet."]
        out += ["", md_image("success vs crash rate", f"{name}.png"), ""]
        if bounds:
            out += multi_leaderboard.upper_bounds_heading()
            out += _rows_table(bounds, ranked=False) + [""]
        out += ["### Table I, every metric", ""]
        cols = [(md(row.name), row.results.summary) for row in ranked]
        cols += [(f"{md(row.name)} (upper bound)", row.results.summary) for row in bounds]
        out.append(render_table(cols, markdown=True).rstrip())
        out.append("")
        out += safety_board.safety_section(ranked + bounds) + safety_board.shield_section(ranked)
    else:
        out += ["No measured submissions yet.", ""]
    if ref is not None:
        out += [
            f"## Reference: {REFERENCE_NOTE}",
            "",
            f"Not measured here. Source: {md(ref['source'])}. These numbers come from another simulator "
            "and are shown for orientation only; they are never ranked with the measured rows.",
            "",
        ]
        keys = [k for k, _, _, _ in TABLE if any(k in row for row in ref["rows"])]
        kinds = {k: (kind, unit) for k, _, kind, unit in TABLE}
        out += ["| decider | " + " | ".join(_LABELS[k] for k in keys) + " |", "|" + "---|" * (len(keys) + 1)]
        for row in ref["rows"]:
            cells = [_reported(row.get(k), *kinds[k]) for k in keys]
            out.append(f"| {md(row['decider'])} ({REFERENCE_NOTE}) | " + " | ".join(cells) + " |")
        out.append("")
    if paper:
        out.append(paper)
    return "\n".join(
        out + multi_leaderboard.flagged_section(list(flagged), _policy_cell) + multi_leaderboard.stale_section(stale)
    )


def _reported(value: Any, kind: str, unit: str) -> str:
    """A number as the paper printed it (no CI: the paper gives none)."""
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return "-"
    return f"{value * 100:.3g} %" if kind == "rate" else f"{value:.1f} {unit}".strip()


def _readme(index: dict[str, Any], head: str = "") -> str:
    out = [
        "# OvertakeZoo leaderboards",
        "",
        "<!-- generated by `overtakezoo leaderboard` from submissions/; do not edit -->",
        "",
        *([head] if head else []),
        "## Suites",
        "",
        "One table per suite, generated from `submissions/`. CI runs `overtakezoo leaderboard --check` "
        "(the files are current) and `overtakezoo leaderboard --verify --sample 1` (every row new or "
        "changed in the pull request re-runs on every scenario, one scenario of each other row; see the "
        "[security model](#security-model)). Privileged deciders (the oracle) are listed apart as upper "
        "bounds and not ranked; the best success rate below is among the ranked rows.",
        "",
        "| suite | version | scenarios | ranked rows | best success rate |",
        "|---|---|---|---|---|",
    ]
    for name, s in index["suites"].items():
        best = s["entries"][0] if s["entries"] else None
        best_txt = f"{best['success_rate'] * 100:.1f} % ({md(best['name'])})" if best else "-"
        out.append(
            f"| {md_link(name, s['table'])} | {md(s['version'] or '-')} | {md(s['count'] or '-')} | "
            f"{len(s['entries'])} | {best_txt} |"
        )
    multi = multi_leaderboard.readme_section(index.get("multi_agent", {}), index.get("crossplay", {}))
    multi += ([""] if multi else []) + drivers.readme_section(index.get("drivers", {}))
    return "\n".join(out + ([""] + multi if multi else [])) + "\n\n" + GUIDE_HEADING + "\n\n" + GUIDE + "\n" + SECURITY
