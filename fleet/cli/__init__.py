"""The ``fleet`` command line: one module per command (``fleet.cli.run``, ``fleet.cli.sim``, ...);
:func:`main` is the entry point. ``docs/cli.md`` is the reference."""

from fleet.cli.main import build_parser, main

__all__ = ["build_parser", "main"]
