"""CLI verbs: each module defines `NAME`, `HELP`, `add_arguments(parser)` and `run(args) -> int`.

Modules here are found automatically; a verb is a thin wrapper over library functions.
"""
