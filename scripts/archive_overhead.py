"""CPU time and peak memory of `eval --archive` against a plain eval (table1, rule-fsm by default).

    python scripts/archive_overhead.py [--suite table1] [--decider rule-fsm] [--repeats 3]
                                       [--out docs/archive-overhead.md]
                                       [-- extra eval arguments, e.g. --scene-every 10]
    python scripts/archive_overhead.py --breakdown   # where the archive's CPU time goes, and zstd levels

``--breakdown`` runs one archived eval in this process with CPU-time counters around the
recorder's stages (capture per step; per group of episodes: the scene, the record templates, the
JSON heads and summaries, the chunk writes), then compresses the archive's own chunks at several
zstd levels (CPU time and ratio, median of 3).

Each run is a fresh `overtakezoo eval` process; plain and archived runs alternate (so load drift
hits both alike). CPU is the child's user + sys time and peak RSS its ru_maxrss, both from
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

from overtakezoo.benchmark.run.perf import interleave, repeat, spread, timed


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


def breakdown(suite_name: str, decider_name: str) -> str:
    """CPU seconds per recorder stage of one in-process archived run, and zstd levels on its chunks."""
    import collections

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

    stages = [
        (recorder.ArchiveRecorder, "_capture", "capture (per step)"),
        (recorder.ArchiveRecorder, "_write_episodes", "writing episodes (all below)"),
        (recorder, "scene_records", "  scene records (/tf, /scene/*)"),
        (cdr.Layout, "fill", "  record templates filled (all kinds)"),
        (recorder.ArchiveRecorder, "_write_chunk", "  chunks: JSON heads and summaries, chunk, metadata"),
        (mcapfile.McapFile, "write_chunk", "    chunk: compress, CRC, message indexes"),
    ]
    for owner, name, key in stages:
        count(owner, name, key)
    suite = load_suite(suite_name)
    decider = zoo.load(decider_name, config=suite.config)
    lines = []
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
        lines += [f"| {key} | {spent[key]:.2f} |" for _, _, key in stages]
        with open(path, "rb") as f:
            summary = make_reader(f).get_summary()
            chunks = []
            for c in summary.chunk_indexes[::8]:
                f.seek(c.chunk_start_offset + 9)
                ch = Chunk.read(ReadDataStream(f))
                chunks.append(zstandard.decompress(ch.data, max_output_size=ch.uncompressed_size))
    raw = sum(map(len, chunks))
    lines += [
        "",
        f"zstd on every 8th chunk of that archive ({raw / 1e6:.0f} MB of records), median of 3:",
        "",
        "| level | MB/s (CPU) | compressed / raw |",
        "|---|---|---|",
    ]
    for level in (3, 1, -1, -3, -5):
        z = zstandard.ZstdCompressor(level=level)
        out = sum(len(z.compress(c)) for c in chunks)  # (untimed: a warm-up)
        cpu = repeat(timed(lambda z=z: sum(len(z.compress(c)) for c in chunks), time.process_time), 3)
        lines.append(f"| {level} | {raw / cpu['median'] / 1e6:.0f} | {out / raw:.3f} |")
    return "\n".join(lines) + "\n"


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
    ap.add_argument("extra", nargs="*", help="extra arguments for the archived eval (after --)")
    a = ap.parse_args()
    if a.breakdown:
        text = breakdown(a.suite, a.decider)
        print(text)
        if a.out:
            Path(a.out).write_text(text)
        return
    rss: dict[str, list[float]] = {"plain": [], "archive": []}

    def eval_cpu(kind: str, args: list[str]) -> float:
        c, m = run_once(args)
        rss[kind].append(m)
        return c

    with tempfile.TemporaryDirectory() as tmp:
        base = ["--suite", a.suite, "--decider", a.decider, "--no-progress", "--out", f"{tmp}/r.json"]
        archived = [*base, "--archive", f"{tmp}/run.mcap", *a.extra]
        # interleaved: plain, archive, plain, archive, ...
        cpu = interleave(
            {"plain": lambda: eval_cpu("plain", base), "archive": lambda: eval_cpu("archive", archived)}, a.repeats
        )
        size = os.path.getsize(f"{tmp}/run.mcap")
    mem = {k: spread(v) for k, v in rss.items()}
    ratio = spread([x / y for x, y in zip(cpu["archive"]["runs"], cpu["plain"]["runs"], strict=True)])
    args = " ".join(a.extra)
    lines = [
        f"`eval --suite {a.suite} --decider {a.decider}` with and without `--archive`{' ' + args if args else ''}; "
        f"{a.repeats} interleaved runs each, fresh processes, medians (range).",
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
        f"Archive size: {size / 1e6:.1f} MB ({size / 1e3 / max(1, _episodes(a.suite)):.0f} KB per episode).",
    ]
    text = "\n".join(lines) + "\n"
    print(text)
    if a.out:
        Path(a.out).write_text(text)


def _episodes(suite: str) -> int:
    from overtakezoo.envs.suites import load_suite

    return load_suite(suite).count


if __name__ == "__main__":
    main()
