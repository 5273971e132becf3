"""Subcommands of the overtakezoo CLI; each module exposes register(subparsers)."""
