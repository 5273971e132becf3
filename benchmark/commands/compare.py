"""``overtakezoo compare``: Table I for two results side by side, with the paired row."""

from __future__ import annotations

from typing import Any

from overtakezoo.benchmark.commands._options import add_parser


def register(subparsers: Any) -> None:
    p = add_parser(
        subparsers,
        "compare",
        "compare two results files (Table I, two columns)",
        'Print Table I for two results of the same suite, including the paired row "crash in the\n'
        'same scenarios" (the share of scenarios in which both crashed). Results from different\n'
        "suite files (hashes) or different scenario ranges are refused.",
        ["overtakezoo compare results/table1/dqn.json results/table1/rule-fsm.json"],
    )
    p.add_argument("a", help="first results file")
    p.add_argument("b", help="second results file")
    p.add_argument("--markdown", action="store_true", help="print a Markdown table")
    p.set_defaults(handler=run)


def run(args: Any) -> int:
    from overtakezoo.benchmark.errors import UserError
    from overtakezoo.benchmark.results.metrics import crash_same_scenarios, render_table
    from overtakezoo.benchmark.results.results import Results

    a, b = Results.load(args.a), Results.load(args.b)
    if a.suite["hash"] != b.suite["hash"]:
        raise UserError(
            f"{args.b}: suite.hash: measured on {b.suite['name']} v{b.suite['version']} "
            f"({b.suite['hash'][:12]}), but {args.a} on {a.suite['name']} v{a.suite['version']} "
            f"({a.suite['hash'][:12]}): not comparable"
        )
    if a.meta["range"] != b.meta["range"]:
        raise UserError(f"{args.b}: range: covers scenarios {b.meta['range']}, {args.a} covers {a.meta['range']}")
    names = [a.decider["name"], b.decider["name"]]
    if names[0] == names[1]:
        names = [f"{names[0]} (a)", f"{names[1]} (b)"]
    print(
        f"suite {a.suite['name']} v{a.suite['version']} ({a.suite['hash'][:12]}), "
        f"scenarios {a.meta['range'][0]}-{a.meta['range'][1] - 1}"
    )
    print(
        render_table(
            list(zip(names, [a.summary, b.summary], strict=True)),
            paired=crash_same_scenarios(a.per, b.per),
            markdown=args.markdown,
        ),
        end="",
    )
    return 0
