"""``overtakezoo suites``: list the built-in suites with their counts and hashes."""

from __future__ import annotations

from typing import Any

from overtakezoo.benchmark.commands._options import add_parser


def register(subparsers: Any) -> None:
    p = add_parser(
        subparsers,
        "suites",
        "list the benchmark suites",
        "List the built-in suites: name, version, scenario count, seed and content hash.",
        ["overtakezoo suites", "overtakezoo suites --full-hash"],
    )
    p.add_argument("--full-hash", action="store_true", help="print the whole sha256 instead of 12 digits")
    p.set_defaults(handler=run)


def run(args: Any) -> int:
    from overtakezoo.envs.suites import list_suites

    rows = [("suite", "version", "count", "seed", "hash", "description")]
    for s in list_suites():
        rows.append(
            (
                s.name,
                str(s.version),
                str(s.count),
                str(s.seed),
                s.hash if args.full_hash else s.hash[:12],
                s.description,
            )
        )
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    for r in rows:
        print("  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip())
    return 0
