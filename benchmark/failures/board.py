"""The failure board: each zoo decider's failures, driven by every other (``leaderboards/failures/``).

For each suite of :data:`SUITES` and each zoo decider (the rows), a failure search (``search.cma_search``,
``budget`` episodes, seed 0) finds that decider's distinct crashes, and random sampling at the same
budget (``search.random_search``) counts what the suite's own draws find. The first :data:`CAP` distinct
failures of each row become a failure suite (``suites/<suite>-<decider>-failures.toml``, an explicit
suite: ``overtakezoo eval --suite leaderboards/failures/suites/...`` re-runs it). Every decider (the
columns, the privileged oracle as an upper bound among them) then drives every row's failure suite:
the **failure cross-table** gives crash and success rates (``README.md``, ``cross-<suite>.png``). The
diagonal re-runs a decider on its own failures (100 % crashes: the failures reproduce).

**Failure maps** (``maps/<decider>.png``, on ``table1``): crashes over a grid of NPC1 gap x NPC2
distance (Fig. 10's axes, as ``decision_map``), each cell coloured by how many of its :data:`MAP_DRAWS`
scenarios crash, their other parameters drawn from the suite's ranges (the same draws for every decider),
with the failures the search found overlaid (their own values of the other parameters differ: a
projection).

Everything is seeded and the files are written whole (``io.atomic_*``): a regeneration with the same
code and zoo gives the same bytes. ``write_failure_board(out_dir)`` regenerates it; the command is
``overtakezoo failure-board`` (benchmark/commands/failure_board.py).
"""

from __future__ import annotations

import io
import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.leaderboard.untrusted import md, md_code, md_image, md_link, plot_text

SUITES = ("table1", "oncoming-4")
BUDGET = 1000  # episodes per search (and per random baseline)
CAP = 200  # failures per row kept in its failure suite and driven by every column
MAP_SUITE = "table1"
MAP_AXES = ("oncoming_gap", "lead_gap")  # x, y: Fig. 10's NPC2 distance and NPC1 gap
MAP_RESOLUTION = 24
MAP_DRAWS = 8
MARKER = ".overtakezoo-failure-board"  # a file that marks a folder as a board (so --out never replaces another)
UPPER_BOUNDS = ("oracle",)


def board_deciders() -> list[str]:
    """The zoo's members without the shield wrapper and not privileged (the rows; the single-ego
    oracle joins them as an upper bound, :data:`UPPER_BOUNDS`)."""
    from overtakezoo import zoo

    return [n for n in zoo.known_names() if "+" not in n and zoo.member(n).kind != "privileged"]


def suite_file_name(suite: str, decider: str) -> str:
    from overtakezoo.benchmark.failures.search import default_name

    class _N:  # (default_name reads .name)
        def __init__(self, name: str) -> None:
            self.name = name

    return f"{default_name(_N(suite), _N(decider))}.toml"


# ------------------------------------------------------------------ jobs (module level: run in worker processes)
def _search_job(args: tuple[str, str, int, int]) -> dict[str, Any]:
    from overtakezoo import zoo
    from overtakezoo.benchmark.failures.search import cma_search, default_name, failure_suite, random_search
    from overtakezoo.envs.suites import load_suite

    suite_name, decider_name, budget, seed = args
    suite = load_suite(suite_name)
    decider = zoo.load(decider_name, suite.config)
    t0 = time.process_time()
    found = cma_search(suite, decider, budget, seed, progress=False)
    rand = random_search(suite, decider, budget, seed, progress=False)
    cpu = time.process_time() - t0
    kept = found.first(CAP)
    data = None
    if kept.distinct:
        data = failure_suite(
            suite,
            decider,
            kept,
            name=default_name(suite, decider),
            seed=seed,
            budget=budget,
            target="crash",
            command=f"overtakezoo failure-board (search --decider {decider_name} "
            f"--suite {suite_name} --budget {budget} --seed {seed})",
        )
    return {
        "suite": suite_name,
        "decider": decider_name,
        "distinct": found.distinct,
        "failing": found.failures,
        "episodes": found.episodes,
        "random_distinct": rand.distinct,
        "random_failing": rand.failures,
        "random_episodes": rand.episodes,
        "kept": kept.distinct,
        "cpu_s": cpu,
        "file": data,
        "values": {k: v.tolist() for k, v in kept.values.items()},
        "version": str(decider.version),
        "weights_sha256": decider.weights_sha256,
    }


def _drive_job(args: tuple[str, bytes, str, list[str]]) -> dict[str, Any]:
    """Every column decider on one row's failure suite: counts of crash, success, timeout."""
    from overtakezoo import zoo
    from overtakezoo.benchmark.run.runner import run_suite
    from overtakezoo.envs.suites import parse_suite

    path, data, row, columns = args
    suite = parse_suite(data, Path(path))
    cells = {}
    for col in columns:
        outcome = run_suite(suite, zoo.load(col, suite.config), progress=False).per_scenario_array("outcome")
        outcome = np.asarray(outcome, np.int64)
        cells[col] = {
            "n": int(outcome.size),
            "crash": int(np.isin(outcome, (2, 4)).sum()),
            "success": int((outcome == 1).sum()),
            "timeout": int((outcome == 3).sum()),
        }
    return {"row": row, "cells": cells}


def map_points(
    suite: Any, seed: int = 0, resolution: int = MAP_RESOLUTION, draws: int = MAP_DRAWS
) -> tuple[Any, np.ndarray, np.ndarray, np.ndarray]:
    """The map's grid: (space, unit points (R*R*K, D), x centres, y centres) over :data:`MAP_AXES`."""
    from overtakezoo.envs.draws import space_for
    from overtakezoo.envs.explicit import base_distribution

    space = space_for(base_distribution(suite), where=f"suite {suite.name!r}")
    labels = [d.label for d in space.dims]
    ix, iy = (labels.index(a) for a in MAP_AXES)
    R, K = resolution, draws
    centres = (np.arange(R) + 0.5) / R
    rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(2)[1])
    unit = rng.uniform(size=(R, R, K, space.size))  # (y, x, draw, dim): the other parameters drawn
    unit[..., ix] = centres[None, :, None]
    unit[..., iy] = centres[:, None, None]
    dx, dy = space.dims[ix], space.dims[iy]
    return space, unit.reshape(-1, space.size), dx.lo + centres * (dx.hi - dx.lo), dy.lo + centres * (dy.hi - dy.lo)


def _map_job(args: tuple[str, str, dict[str, list[float]], int, int, int, int]) -> dict[str, Any]:
    from overtakezoo import zoo
    from overtakezoo.benchmark.failures.search import evaluate
    from overtakezoo.envs.suites import load_suite

    suite_name, decider_name, failures, budget, resolution, draws, total = args
    suite = load_suite(suite_name)
    space, unit, xs, ys = map_points(suite, 0, resolution, draws)
    ev = evaluate(suite, zoo.load(decider_name, suite.config), space.build(unit))
    rate = ev.failed.reshape(resolution, resolution, draws).mean(axis=2)
    png = map_png(decider_name, suite, xs, ys, rate, failures, budget, draws, total)
    return {"decider": decider_name, "png": png, "cells_failing": int((rate > 0).sum())}


def map_png(
    decider: str,
    suite: Any,
    xs: np.ndarray,
    ys: np.ndarray,
    rate: np.ndarray,
    failures: dict[str, list[float]],
    budget: int,
    draws: int = MAP_DRAWS,
    total: int | None = None,
) -> bytes:
    """The failure map as PNG bytes (Agg canvas, no timestamps)."""
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import BoundaryNorm, ListedColormap
    from matplotlib.figure import Figure

    # Counts of crashing scenarios per cell, 0 white and every count >= 1 clearly red (a rare crash shows).
    reds = matplotlib.colormaps["Reds"](np.linspace(0.3, 1.0, draws))
    cmap = ListedColormap(np.vstack([[1.0, 1.0, 1.0, 1.0], reds]))
    norm = BoundaryNorm(np.arange(draws + 2) - 0.5, cmap.N)
    counts = np.rint(rate * draws)
    with matplotlib.rc_context({"font.family": "DejaVu Sans", "font.size": 9}):
        fig = Figure(figsize=(7.0, 5.2), dpi=100)
        FigureCanvasAgg(fig)
        ax = fig.add_subplot(1, 1, 1)
        hx, hy = (xs[1] - xs[0]) / 2, (ys[1] - ys[0]) / 2
        extent = (xs[0] - hx, xs[-1] + hx, ys[0] - hy, ys[-1] + hy)
        im = ax.imshow(
            counts, origin="lower", aspect="auto", extent=extent, cmap=cmap, norm=norm, interpolation="nearest"
        )
        fx, fy = failures.get(MAP_AXES[0], []), failures.get(MAP_AXES[1], [])
        if len(fx):
            ax.scatter(
                fx,
                fy,
                s=14,
                marker="x",
                color="#1f3b73",
                linewidths=0.9,
                label=f"distinct crashes found by the search in {budget} episodes ({len(fx)}"
                + (f" of {total} shown)" if total and total > len(fx) else ")"),
            )
            ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.13), fontsize=8, frameon=False)
        else:
            ax.text(
                0.5,
                -0.16,
                f"no crash found by the search in {budget} episodes",
                transform=ax.transAxes,
                ha="center",
                va="center",
                fontsize=8,
            )
        ax.set_xlim(extent[0], extent[1])
        ax.set_ylim(extent[2], extent[3])
        ax.set_xlabel("NPC2 (oncoming) distance D2 from the ego's front (m)")
        ax.set_ylabel("NPC1 (lead) gap D1 (m)")
        ax.set_title(
            f"{plot_text(decider)} on {plot_text(suite.name)}: where it crashes\n"
            f"(each cell: {draws} scenarios, NPC speeds drawn from the suite's ranges)",
            fontsize=9,
        )
        cb = fig.colorbar(im, ax=ax, fraction=0.046, pad=0.03, ticks=range(draws + 1))
        cb.set_label(f"crashes among the cell's {draws} scenarios")
        fig.tight_layout()
        buf = io.BytesIO()
        fig.savefig(buf, format="png", metadata={"Software": None})
    return buf.getvalue()


JOBS = {"search": _search_job, "drive": _drive_job, "map": _map_job}


def _pool_map(kind: str, todo: list[Any], jobs: int) -> list[Any]:
    """``JOBS[kind]`` over ``todo``, in order; with ``jobs`` > 1 in that many worker processes, each
    taking every ``jobs``-th task. Workers get their tasks as JSON on stdin and answer JSON on stdout
    (bytes as base64): nothing is pickled."""
    if jobs <= 1 or len(todo) <= 1:
        return [JOBS[kind](t) for t in todo]
    from concurrent.futures import ThreadPoolExecutor

    jobs = min(jobs, len(todo))
    shards = [todo[i::jobs] for i in range(jobs)]
    with ThreadPoolExecutor(jobs) as pool:
        answers = list(pool.map(lambda shard: _worker(kind, shard), shards))
    out: list[Any] = [None] * len(todo)
    for i, answer in enumerate(answers):
        out[i::jobs] = answer
    return out


def _worker(kind: str, shard: list[Any]) -> list[Any]:
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, "-m", "overtakezoo.benchmark.failures.board", "--worker", kind],
        input=json.dumps(_encode(shard)).encode(),
        capture_output=True,
    )
    if done.returncode != 0:
        tail = done.stderr.decode(errors="replace").strip().splitlines()[-1:] or ["(no message)"]
        raise RuntimeError(f"failure-board worker ({kind}) failed: {tail[0]}")
    return _decode(json.loads(done.stdout))


def _encode(obj: Any) -> Any:
    import base64

    if isinstance(obj, bytes):
        return {"__base64__": base64.b64encode(obj).decode()}
    if isinstance(obj, dict):
        return {k: _encode(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_encode(v) for v in obj]
    return obj


def _decode(obj: Any) -> Any:
    import base64

    if isinstance(obj, dict):
        if set(obj) == {"__base64__"}:
            return base64.b64decode(obj["__base64__"])
        return {k: _decode(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_decode(v) for v in obj]
    return obj


# ------------------------------------------------------------------ the board
def board_columns(rows: list[str], upper_bounds: bool = True) -> list[str]:
    """Who drives: the rows, then the privileged upper bounds (the oracle)."""
    from overtakezoo import zoo

    return rows + ([u for u in UPPER_BOUNDS if u in zoo.known_names() and u not in rows] if upper_bounds else [])


def measure(
    out_dir: Path,
    suites: tuple[str, ...] = SUITES,
    deciders: list[str] | None = None,
    budget: int = BUDGET,
    seed: int = 0,
    jobs: int = 1,
    maps: bool = True,
    upper_bounds: bool = True,
) -> dict[str, Any]:
    """Run everything; returns the files (relative name -> bytes) and the data document."""
    from overtakezoo import zoo
    from overtakezoo.envs.suites import load_suite

    rows = deciders or board_deciders()
    columns = board_columns(rows, upper_bounds)
    t0 = time.perf_counter()
    searched = _pool_map("search", [(s, d, budget, seed) for s in suites for d in rows], jobs)
    files: dict[str, bytes] = {}
    drive = []
    for r in searched:
        if r["file"] is not None:
            name = f"suites/{suite_file_name(r['suite'], r['decider'])}"
            files[name] = r["file"]
            drive.append((str(out_dir / name), r["file"], f"{r['suite']}/{r['decider']}", columns))
    driven = {d["row"]: d["cells"] for d in _pool_map("drive", drive, jobs)}
    if maps:
        todo = [
            (MAP_SUITE, r["decider"], r["values"], budget, MAP_RESOLUTION, MAP_DRAWS, r["distinct"])
            for r in searched
            if r["suite"] == MAP_SUITE
        ]
        for m in _pool_map("map", todo, jobs):
            files[f"maps/{m['decider']}.png"] = m["png"]
    wall = time.perf_counter() - t0
    doc = {
        "generated_by": "overtakezoo failure-board",
        "budget": budget,
        "seed": seed,
        "cap": CAP,
        "suites": {},
        "rows": rows,
        "columns": columns,
        "deciders": {},
        "map": {"suite": MAP_SUITE, "axes": list(MAP_AXES), "resolution": MAP_RESOLUTION, "draws": MAP_DRAWS}
        if maps
        else None,
    }
    for s in suites:
        suite = load_suite(s)
        doc["suites"][s] = {"version": suite.version, "hash": suite.hash, "count": suite.count, "rows": {}}
    for r in searched:
        doc["deciders"][r["decider"]] = {"version": r["version"], "weights_sha256": r["weights_sha256"]}
        key = f"{r['suite']}/{r['decider']}"
        doc["suites"][r["suite"]]["rows"][r["decider"]] = {
            k: r[k]
            for k in ("distinct", "failing", "episodes", "random_distinct", "random_failing", "random_episodes", "kept")
        } | {
            "file": f"suites/{suite_file_name(r['suite'], r['decider'])}" if r["file"] else None,
            "cells": driven.get(key),
        }
    for c in columns:
        if c not in doc["deciders"]:
            d = zoo.load(c)
            doc["deciders"][c] = {"version": str(d.version), "weights_sha256": d.weights_sha256}
    cpu = sum(r["cpu_s"] for r in searched)
    timing = {"wall_s": round(wall, 1), "search_cpu_s": round(cpu, 1), "jobs": jobs}
    files["board.json"] = (json.dumps(doc, indent=1, sort_keys=True) + "\n").encode()
    for s in suites:
        files[f"cross-{s}.png"] = cross_png(doc, s)
    files["README.md"] = markdown(doc).encode()
    return {"files": files, "doc": doc, "timing": timing}


def _rate(cell: dict[str, int] | None, key: str) -> float | None:
    return None if not cell or not cell["n"] else cell[key] / cell["n"]


def markdown(doc: dict[str, Any]) -> str:
    b, cap = doc["budget"], doc["cap"]
    out = [
        "# Failure board",
        "",
        "<!-- generated by `overtakezoo failure-board --out leaderboards/failures` "
        "(benchmark/failures/board.py); do not edit -->",
        "",
        f"Each row is a zoo decider whose failures were searched for: CMA-ES failure search (`overtakezoo search "
        f"--decider NAME --suite SUITE --budget {b} --seed {doc['seed']}`, every parameter range of the suite) "
        f"and, for comparison, random sampling of the suite at the same budget ({b} episodes each). A failure is a "
        "crash (or leaving the road); failures count once (distinct: more than 5 % of some range apart). The first "
        f"{cap} distinct failures of each row are its failure suite (`suites/`, an explicit suite: "
        "`overtakezoo eval --suite leaderboards/failures/suites/FILE --decider NAME` re-runs it), and every "
        "decider drives every row's failure suite: the columns. The diagonal is a decider on its own failures "
        "(all crash again: the failures reproduce). The oracle (privileged, it simulates the future) is a column "
        "only, as an upper bound: where it succeeds, the failure was avoidable.",
        "",
    ]
    for s, info in doc["suites"].items():
        rows, cols = doc["rows"], doc["columns"]
        out += [
            f"## {md(s)}",
            "",
            f"Suite {md_code(s)} v{md(info['version'])}, sha256 {md_code(info['hash'][:12])}.",
            "",
            "| decider (whose failures) | distinct failures, search | random sampling | ratio | failure suite |",
            "|---|---|---|---|---|",
        ]
        for r in rows:
            row = info["rows"].get(r)
            if row is None:
                continue
            ratio = (
                f"{(row['distinct'] / row['episodes']) / (row['random_distinct'] / row['random_episodes']):.1f}x"
                if row["random_distinct"]
                else ("-" if not row["distinct"] else "random found none")
            )
            link = md_link(Path(row["file"]).name, row["file"]) + f" ({row['kept']})" if row["file"] else "none found"
            out.append(
                f"| {md(r)} | {row['distinct']} in {row['episodes']} | {row['random_distinct']} in "
                f"{row['random_episodes']} | {ratio} | {link} |"
            )
        out += [
            "",
            "Crash rate (%) of the column decider on the row's failures:",
            "",
            "| failures of \\ driven by | " + " | ".join(map(md, cols)) + " |",
            "|" + "---|" * (len(cols) + 1),
        ]
        for key in ("crash", "success"):
            if key == "success":
                out += [
                    "",
                    "Success rate (%) of the column decider on the row's failures:",
                    "",
                    "| failures of \\ driven by | " + " | ".join(map(md, cols)) + " |",
                    "|" + "---|" * (len(cols) + 1),
                ]
            for r in rows:
                row = info["rows"].get(r)
                if not row or not row["cells"]:
                    continue
                cells = []
                for c in cols:
                    v = _rate(row["cells"].get(c), key)
                    cells.append("-" if v is None else f"{100 * v:.0f}")
                out.append(f"| **{md(r)}** ({row['kept']}) | " + " | ".join(cells) + " |")
        out += ["", md_image(f"failure cross-table, {s}", f"cross-{s}.png"), ""]
    if doc["map"]:
        m = doc["map"]
        out += [
            "## Failure maps",
            "",
            f"Where each decider crashes on {md_code(m['suite'])} over NPC2 distance x NPC1 gap (the paper's "
            f"Fig. 10 axes): a {m['resolution']} x {m['resolution']} grid, each cell coloured by how many of its "
            f"{m['draws']} scenarios crash, their other parameters (the NPC speeds) drawn from the suite's ranges, "
            "the same draws for every decider; crosses: the distinct crashes the search found (their speeds are "
            "their own: a projection).",
            "",
        ]
        for r in doc["rows"]:
            if m["suite"] in doc["suites"] and r in doc["suites"][m["suite"]]["rows"]:
                out.append(f"- {md_link(r, f'maps/{r}.png')}")
        out.append("")
    versions = ", ".join(
        f"{md(n)} v{md(d['version'])}" + (f" {md_code(str(d['weights_sha256'])[:10])}" if d["weights_sha256"] else "")
        for n, d in sorted(doc["deciders"].items())
    )
    out += [f"Deciders: {versions}.", ""]
    return "\n".join(out)


def cross_png(doc: dict[str, Any], suite: str) -> bytes:
    """Crash and success rates of the cross-table of ``suite`` as two heatmaps (Agg, no timestamps)."""
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    info = doc["suites"][suite]
    rows = [r for r in doc["rows"] if info["rows"].get(r, {}).get("cells")]
    cols = doc["columns"]
    with matplotlib.rc_context({"font.family": "DejaVu Sans", "font.size": 8}):
        fig = Figure(figsize=(13.0, 0.42 * max(len(rows), 3) + 2.6), dpi=100)
        FigureCanvasAgg(fig)
        for i, (key, label, cmap) in enumerate(
            (("crash", "crash rate", "Reds"), ("success", "success rate", "Greens"))
        ):
            ax = fig.add_subplot(1, 2, i + 1)
            m = np.array([[100.0 * (_rate(info["rows"][r]["cells"].get(c), key) or 0.0) for c in cols] for r in rows])
            if not rows:
                m = np.zeros((1, len(cols)))
            im = ax.imshow(m, vmin=0, vmax=100, cmap=cmap, aspect="auto")
            for a in range(len(rows)):
                for c in range(len(cols)):
                    ax.text(
                        c,
                        a,
                        f"{m[a, c]:.0f}",
                        ha="center",
                        va="center",
                        fontsize=7,
                        color="white" if m[a, c] > 60 else "black",
                    )
            ax.set_xticks(range(len(cols)), [plot_text(x) for x in cols], rotation=45, ha="right")
            ax.set_yticks(
                range(len(rows)),
                [f"{plot_text(r)} ({info['rows'][r]['kept']})" for r in rows] if i == 0 else [""] * len(rows),
            )
            ax.set_xlabel("driven by")
            if i == 0:
                ax.set_ylabel("failures of (distinct failures driven)")
            ax.set_title(f"{label} (%)")
            fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04)
        fig.suptitle(
            f"{plot_text(suite)}: each decider's failures (search, {doc['budget']} episodes) driven by every decider"
        )
        fig.tight_layout()
        buf = io.BytesIO()
        fig.savefig(buf, format="png", metadata={"Software": None})
    return buf.getvalue()


def write_failure_board(
    out_dir: str | Path = "leaderboards/failures",
    jobs: int = 1,
    budget: int = BUDGET,
    deciders: list[str] | None = None,
    suites: tuple[str, ...] = SUITES,
    maps: bool = True,
    upper_bounds: bool = True,
) -> dict[str, Any]:
    """Measure and write the board into ``out_dir`` as one swap (``io.atomic_directory``): the folder is
    the old board or the new one, never a mix. A folder that is not a board (no marker file) and is
    not empty is refused, so ``--out`` cannot replace anything else."""
    from overtakezoo.envs.io import atomic_directory, check_writable_dir

    out = Path(out_dir)
    if out.exists() and (not out.is_dir() or (any(out.iterdir()) and not (out / MARKER).is_file())):
        raise UserError(f"{out}: exists and is not a failure board (no {MARKER}); choose a new or empty folder")
    check_writable_dir(out.parent)  # an unwritable place fails now, not after the minutes of measuring
    result = measure(out, suites, deciders, budget, 0, jobs, maps, upper_bounds)
    with atomic_directory(out) as tmp:
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o777 & ~umask)  # (a temp folder is private; the board is an ordinary folder)
        (tmp / MARKER).write_text("a folder written by `overtakezoo failure-board`; it replaces the whole folder\n")
        for rel, data in sorted(result["files"].items()):
            path = tmp / rel
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data)
    return result


if __name__ == "__main__":  # a worker of _pool_map: JSON tasks on stdin, JSON answers on stdout
    import sys

    if len(sys.argv) != 3 or sys.argv[1] != "--worker" or sys.argv[2] not in JOBS:
        raise SystemExit("usage: python -m overtakezoo.benchmark.failures.board --worker search|drive|map")
    tasks = _decode(json.loads(sys.stdin.buffer.read()))
    sys.stdout.write(json.dumps(_encode([JOBS[sys.argv[2]](t) for t in tasks])))
