"""The ``fleet`` command line: one module per command (``fleet.cli.run``, ``fleet.cli.sim``, ...);
:func:`fleet.cli.main.main` is the entry point. ``docs/cli.md`` is the reference."""
