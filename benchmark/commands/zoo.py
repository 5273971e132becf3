"""``overtakezoo zoo list``: the registered deciders with their model cards."""

from __future__ import annotations

import textwrap
from typing import Any

from overtakezoo.benchmark.commands._options import add_parser
from overtakezoo.benchmark.errors import UserError


def register(subparsers: Any) -> None:
    p = add_parser(
        subparsers,
        "zoo",
        "list the deciders of the zoo",
        "Work with the decider zoo. 'list' prints every registered decider (or the named ones) with its model card.",
        ["overtakezoo zoo list", "overtakezoo zoo list rule-fsm oracle", "overtakezoo zoo list --names"],
    )
    sub = p.add_subparsers(dest="zoo_command", metavar="ACTION")
    ls = sub.add_parser(
        "list",
        help="print each decider with its model card",
        description="Print each registered decider: name, version, privileged flag and model card.",
    )
    ls.add_argument("names", nargs="*", metavar="NAME", help="only these deciders (default: all)")
    ls.add_argument("--names", dest="names_only", action="store_true", help="print the names only, one a line")
    ls.set_defaults(handler=run_list)
    p.set_defaults(handler=lambda args: _usage(p))


def _usage(parser: Any) -> int:
    parser.print_help()
    return 2


def run_list(args: Any) -> int:
    from overtakezoo import zoo

    known = zoo.names()
    wanted = args.names or known
    unknown = [n for n in wanted if n not in known]
    if unknown:
        raise UserError(f"unknown decider {unknown[0]!r} (known: {', '.join(known)})")
    if args.names_only:
        print("\n".join(wanted))
        return 0
    for name in wanted:
        try:
            d = zoo.load(name)
            head = f"{name}  v{d.version}" + ("  [privileged]" if d.privileged else "")
            if d.weights_sha256:
                head += f"  sha256 {d.weights_sha256[:12]}"
            card = d.card()
        except Exception as exc:  # a member whose weights are missing still gets listed, with why
            head, card = name, f"(cannot load: {exc})"
        print(head)
        print(textwrap.indent(textwrap.fill(" ".join(card.split()), width=96), "    "))
    return 0
