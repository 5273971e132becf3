"""CPU time and peak memory of `eval --archive` against a plain eval (table1, rule-fsm by default).

    python scripts/archive_overhead.py [--suite table1] [--decider rule-fsm] [--repeats 3]
                                       [--out docs/archive-overhead.md]
                                       [-- extra eval arguments, e.g. --scene-every 10]
    python scripts/archive_overhead.py --breakdown   # where the archive's CPU time goes, and zstd levels
    python scripts/archive_overhead.py --repeats 5 --json docs/archive-overhead.json   # all of it, stored

``--breakdown`` runs one archived eval in this process with CPU-time counters around the
recorder's stages (capture per step; per group of episodes: the scene, the record templates, the
JSON heads and summaries, the chunk writes), counts the bytes of records per topic, then
compresses the archive's own chunks at several zstd levels (CPU time and ratio, median of 3).

``--json PATH`` runs the whole report that docs/archive-overhead.md and docs/archives.md quote:
the A/B with the default archive (the scene at every step), the A/B with ``--scene-every 0``, and
the breakdown, and writes every figure under an id (median, min, max, runs, unit, what) with the
date, the machine and the load average to PATH, atomically.

Each A/B run is a fresh `overtakezoo eval` process; plain and archived runs alternate (so load
drift hits both alike). CPU is the child's user + sys time and peak RSS its ru_maxrss, both from
os.wait4 (CPU time, not wall time: the machine is shared). Prints a markdown table of medians
(repeated and summarised by the perf report's helpers, benchmark/run/perf.py).
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from overtakezoo.benchmark.run.perf import interleave, load_average, machine, repeat, spread, timed
from overtakezoo.envs.io import atomic_write_json

ZSTD_LEVELS = (3, 1, -1, -3, -5)


def run_once(args: list[str]) -> tuple[float, float]:
    """(user + sys CPU seconds, peak RSS MB) of one eval process."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "overtakezoo.benchmark.cli", "eval", *args],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    _, status, ru = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    err = proc.stderr.read().decode() if proc.stderr else ""
    if proc.returncode != 0:
        raise SystemExit(f"eval {' '.join(args)} failed ({proc.returncode}):\n{err}")
    return ru.ru_utime + ru.ru_stime, ru.ru_maxrss / 1024  # ru_maxrss is in KiB on Linux


def cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def figure(fid: str, values: float | list[float] | dict[str, Any], unit: str, what: str, nd: int = 3) -> dict:
    """One figure of the JSON report: the spread of ``values`` (a number is a single run), rounded."""
    s = values if isinstance(values, dict) else spread(values if isinstance(values, list) else [values])
    out = {k: round(s[k], nd) for k in ("median", "min", "max")}
    return {"id": fid, **out, "runs": [round(x, nd) for x in s["runs"]], "unit": unit, "what": what}


def breakdown(suite_name: str, decider_name: str) -> tuple[str, list[dict]]:
    """CPU seconds per recorder stage of one in-process archived run, the bytes of records per
    topic, and zstd levels on its chunks: the markdown and the figures."""
    import collections

    import numpy as np
    import zstandard
    from mcap.data_stream import ReadDataStream
    from mcap.reader import make_reader
    from mcap.records import Chunk

    from overtakezoo import zoo
    from overtakezoo.benchmark.archive import cdr, mcapfile, recorder
    from overtakezoo.benchmark.run.runner import run_suite
    from overtakezoo.envs.suites import load_suite

    spent: dict[str, float] = collections.defaultdict(float)

    def count(owner, name, key):
        inner = getattr(owner, name)

        def timed(*a, **k):
            t = time.process_time()
            try:
                return inner(*a, **k)
            finally:
                spent[key] += time.process_time() - t

        setattr(owner, name, timed)

    # bytes and messages of records per topic, from each chunk's record sizes (before compression)
    volume: dict[str, float] = collections.defaultdict(float)
    messages: dict[str, int] = collections.defaultdict(int)
    write_chunk = mcapfile.McapFile.write_chunk

    def counted_chunk(self, parts, channel, log_time, size):
        cids, inverse = np.unique(channel, return_inverse=True)
        for cid, nbytes, n in zip(cids, np.bincount(inverse, weights=size), np.bincount(inverse), strict=True):
            topic = self.channels[int(cid) - 1].topic
            volume[topic] += float(nbytes)
            messages[topic] += int(n)
        return write_chunk(self, parts, channel, log_time, size)

    mcapfile.McapFile.write_chunk = counted_chunk
    stages = [
        (recorder.ArchiveRecorder, "_capture", "capture (per step)", "capture"),
        (recorder.ArchiveRecorder, "_write_episodes", "writing episodes (all below)", "write-episodes"),
        (recorder, "scene_records", "  scene records (/tf, /scene/*)", "scene-records"),
        (cdr.Layout, "fill", "  record templates filled (all kinds)", "templates"),
        (
            recorder.ArchiveRecorder,
            "_write_chunk",
            "  chunks: JSON heads and summaries, chunk, metadata",
            "chunks",
        ),
        (mcapfile.McapFile, "write_chunk", "    chunk: compress, CRC, message indexes", "chunk-write"),
    ]
    for owner, name, key, _ in stages:
        count(owner, name, key)
    suite = load_suite(suite_name)
    decider = zoo.load(decider_name, config=suite.config)
    lines = []
    what = f"in-process run_suite of {suite_name} with {decider_name} and the archive (scene at every step)"
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "run.mcap"
        t0 = time.process_time()
        with recorder.ArchiveRecorder(path) as rec:
            run_suite(suite, decider, progress=False, recorder=rec)
        total = time.process_time() - t0
        lines += [
            f"In-process `run_suite` of {suite_name} with {decider_name} and the archive: {total:.2f} CPU s.",
            "",
            "| stage | CPU s |",
            "|---|---|",
        ]
        lines += [f"| {key} | {spent[key]:.2f} |" for _, _, key, _ in stages]
        with open(path, "rb") as f:
            summary = make_reader(f).get_summary()
            chunks = []
            for c in summary.chunk_indexes[::8]:
                f.seek(c.chunk_start_offset + 9)
                ch = Chunk.read(ReadDataStream(f))
                chunks.append(zstandard.decompress(ch.data, max_output_size=ch.uncompressed_size))
    figures = [figure("breakdown-total", total, "CPU s", f"{what}: CPU time of the whole run", 2)]
    figures += [
        figure(f"breakdown-{fid}", spent[key], "CPU s", f"{what}: {key.strip()}", 2) for _, _, key, fid in stages
    ]
    steps = messages["/state"]
    groups = {
        "state": volume["/state"],
        "tf": volume["/tf"],
        "rollouts": volume["/scene/rollouts"],
        "rest": sum(volume.values()) - volume["/state"] - volume["/tf"] - volume["/scene/rollouts"],
    }
    lines += ["", "| records (before compression) | MB |", "|---|---|"]
    lines += [f"| {k} | {v / 1e6:.0f} |" for k, v in groups.items()]
    lines += [f"| all | {sum(volume.values()) / 1e6:.0f} |"]
    figures += [
        figure("records-all", sum(volume.values()) / 1e6, "MB", f"{what}: bytes of records before compression", 1)
    ]
    figures += [
        figure(f"records-{k}", v / 1e6, "MB", f"{what}: bytes of {k} records before compression", 1)
        for k, v in groups.items()
    ]
    figures += [
        figure("records-per-step", sum(volume.values()) / steps / 1e3, "KB", f"{what}: record bytes per step", 2),
        figure(
            "state-and-tf-per-step",
            (volume["/state"] + volume["/tf"]) / steps / 1e3,
            "KB",
            f"{what}: bytes of the /state and /tf records of one step",
            2,
        ),
        figure(
            "rollout-redraw",
            volume["/scene/rollouts"] / max(1, messages["/scene/rollouts"]) / 1e3,
            "KB",
            f"{what}: bytes of one /scene/rollouts record (a redraw)",
            2,
        ),
    ]
    raw = sum(map(len, chunks))
    lines += [
        "",
        f"zstd on every 8th chunk of that archive ({raw / 1e6:.0f} MB of records), median of 3:",
        "",
        "| level | MB/s (CPU) | compressed / raw |",
        "|---|---|---|",
    ]
    zstd = {}
    for level in ZSTD_LEVELS:
        z = zstandard.ZstdCompressor(level=level)
        out = sum(len(z.compress(c)) for c in chunks)  # (untimed: a warm-up)
        cpu = repeat(timed(lambda z=z: sum(len(z.compress(c)) for c in chunks), time.process_time), 3)
        zstd[level] = (raw / cpu["median"] / 1e6, out / raw)
        lines.append(f"| {level} | {zstd[level][0]:.0f} | {out / raw:.3f} |")
        speeds = [raw / x / 1e6 for x in cpu["runs"]]
        name = f"zstd-{'minus' if level < 0 else ''}{abs(level)}"
        zwhat = f"zstd level {level} on every 8th chunk of that archive ({raw / 1e6:.0f} MB of records)"
        figures += [
            figure(f"{name}-speed", speeds, "MB/s", f"{zwhat}: MB per CPU second, median of 3", 0),
            figure(f"{name}-ratio", out / raw, "", f"{zwhat}: compressed / raw", 3),
        ]
    figures += [
        figure("zstd-minus3-vs-1-speed", zstd[-3][0] / zstd[1][0], "x", "zstd level -3's speed / level 1's", 2),
        figure("zstd-minus3-vs-1-bytes", zstd[-3][1] / zstd[1][1] - 1, "", "zstd level -3's bytes / level 1's - 1", 3),
        figure(
            "zstd-minus5-vs-minus3-bytes",
            zstd[-5][1] / zstd[-3][1] - 1,
            "",
            "zstd level -5's bytes / level -3's - 1",
            3,
        ),
    ]
    return "\n".join(lines) + "\n", figures


def ab(suite: str, decider: str, repeats: int, extra: list[str]) -> dict[str, Any]:
    """Plain and archived evals, interleaved: the CPU and peak RSS spreads, their ratio, the file's size."""
    rss: dict[str, list[float]] = {"plain": [], "archive": []}

    def eval_cpu(kind: str, args: list[str]) -> float:
        c, m = run_once(args)
        rss[kind].append(m)
        return c

    with tempfile.TemporaryDirectory() as tmp:
        base = ["--suite", suite, "--decider", decider, "--no-progress", "--out", f"{tmp}/r.json"]
        archived = [*base, "--archive", f"{tmp}/run.mcap", *extra]
        # interleaved: plain, archive, plain, archive, ...
        cpu = interleave(
            {"plain": lambda: eval_cpu("plain", base), "archive": lambda: eval_cpu("archive", archived)}, repeats
        )
        size = os.path.getsize(f"{tmp}/run.mcap")
    return {
        "cpu": cpu,
        "mem": {k: spread(v) for k, v in rss.items()},
        "ratio": spread([x / y for x, y in zip(cpu["archive"]["runs"], cpu["plain"]["runs"], strict=True)]),
        "size": size,
        "episodes": _episodes(suite),
    }


def ab_table(r: dict[str, Any], suite: str, decider: str, repeats: int, extra: list[str]) -> str:
    cpu, mem, ratio, size = r["cpu"], r["mem"], r["ratio"], r["size"]
    args = " ".join(extra)
    lines = [
        f"`eval --suite {suite} --decider {decider}` with and without `--archive`{' ' + args if args else ''}; "
        f"{repeats} interleaved runs each, fresh processes, medians (range).",
        f"Machine: {cpu_name()}, {os.cpu_count()} cores, Python {platform.python_version()}; "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}.",
        "",
        "| run | CPU time (user + sys) | peak RSS |",
        "|---|---|---|",
        *(
            f"| {label} | {cpu[k]['median']:.2f} s ({cpu[k]['min']:.2f} - {cpu[k]['max']:.2f}) | "
            f"{mem[k]['median']:.0f} MB ({mem[k]['min']:.0f} - {mem[k]['max']:.0f}) |"
            for k, label in (("plain", "plain eval"), ("archive", "eval --archive"))
        ),
        f"| ratio | {ratio['median']:.1f} x ({ratio['min']:.1f} - {ratio['max']:.1f}) | |",
        "",
        f"Archive size: {size / 1e6:.1f} MB ({size / 1e3 / max(1, r['episodes']):.0f} KB per episode).",
    ]
    return "\n".join(lines) + "\n"


def ab_figures(r: dict[str, Any], prefix: str, how: str) -> list[dict]:
    """The A/B's figures, ids ``PREFIX-...``."""
    return [
        figure(f"{prefix}-plain-cpu", r["cpu"]["plain"], "CPU s", f"plain eval, {how}: user + sys CPU time", 2),
        figure(f"{prefix}-archive-cpu", r["cpu"]["archive"], "CPU s", f"eval --archive, {how}: user + sys CPU time", 2),
        figure(f"{prefix}-cpu-ratio", r["ratio"], "x", f"{how}: CPU time with the archive / without it, per pair", 2),
        figure(
            f"{prefix}-cpu-added",
            r["cpu"]["archive"]["median"] - r["cpu"]["plain"]["median"],
            "CPU s",
            f"{how}: median CPU time with the archive - median without it",
            2,
        ),
        figure(f"{prefix}-plain-rss", r["mem"]["plain"], "MB", f"plain eval, {how}: peak RSS (ru_maxrss)", 1),
        figure(f"{prefix}-archive-rss", r["mem"]["archive"], "MB", f"eval --archive, {how}: peak RSS (ru_maxrss)", 1),
        figure(f"{prefix}-size", r["size"] / 1e6, "MB", f"{how}: the archive's size", 1),
        figure(
            f"{prefix}-size-per-episode",
            r["size"] / 1e3 / max(1, r["episodes"]),
            "KB",
            f"{how}: the archive's size per episode",
            1,
        ),
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--suite", default="table1")
    ap.add_argument("--decider", default="rule-fsm")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", help="also write the table (markdown) to this file")
    ap.add_argument(
        "--breakdown",
        action="store_true",
        help="CPU time per recorder stage (one in-process run) and zstd levels on its chunks, instead of the A/B",
    )
    ap.add_argument(
        "--json",
        metavar="PATH",
        help="the whole report (A/B with the default archive, A/B with --scene-every 0, the breakdown), "
        "every figure by id, written to PATH (docs/archive-overhead.json)",
    )
    ap.add_argument("extra", nargs="*", help="extra arguments for the archived eval (after --)")
    a = ap.parse_args()
    if a.json:
        if a.extra or a.breakdown:
            ap.error("--json runs its own fixed set (no extra eval arguments, no --breakdown)")
        report(a.suite, a.decider, a.repeats, a.json)
        return
    if a.breakdown:
        text, _ = breakdown(a.suite, a.decider)
        print(text)
        if a.out:
            Path(a.out).write_text(text)
        return
    text = ab_table(ab(a.suite, a.decider, a.repeats, a.extra), a.suite, a.decider, a.repeats, a.extra)
    print(text)
    if a.out:
        Path(a.out).write_text(text)


def report(suite: str, decider: str, repeats: int, out: str) -> None:
    import mcap
    import zstandard

    start, t0 = load_average(), time.perf_counter()
    doc: dict[str, Any] = {
        "generated_by": f"python scripts/archive_overhead.py --repeats {repeats} --json {out}",
        "date": time.strftime("%Y-%m-%d %H:%M"),
        "machine": {**machine(), "mcap": mcap.__version__, "zstandard": zstandard.__version__},
        "suite": suite,
        "decider": decider,
        "repeats": repeats,
        "load_average_at_start": start,
    }
    figures = []
    for prefix, extra, how in (
        ("default", [], "the scene at every step"),
        ("state-only", ["--scene-every", "0"], "--scene-every 0 (state topics only)"),
    ):
        r = ab(suite, decider, repeats, extra)
        print(ab_table(r, suite, decider, repeats, extra))
        figures += ab_figures(r, prefix, f"eval --suite {suite} --decider {decider}, {how}, {repeats} interleaved runs")
    text, more = breakdown(suite, decider)
    print(text)
    doc["figures"] = figures + more
    doc["load_average_at_end"] = load_average()
    doc["wall_s"] = round(time.perf_counter() - t0, 1)
    atomic_write_json(out, doc)
    print(f"wrote {out}")


def _episodes(suite: str) -> int:
    from overtakezoo.envs.suites import load_suite

    return load_suite(suite).count


if __name__ == "__main__":
    main()
