"""``fleet config-schema``: the JSON Schema of fleet config files, for editors."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from fleet.cli.common import EXIT_ERROR, EXIT_OK, SubParsers, add_command

EPILOG = """\
examples:
  fleet config-schema                              # print the schema
  fleet config-schema --out docs/config.schema.json

point an editor at it, e.g. with the YAML extension of VS Code, by a first line in the config:
  # yaml-language-server: $schema=../docs/config.schema.json
(the path is relative to the config file; see docs/config.md)
"""


def add_parser(sub: SubParsers) -> argparse.ArgumentParser:
    """Add ``fleet config-schema`` to ``fleet``'s subcommands."""
    p = add_command(
        sub,
        "config-schema",
        handle,
        help="print the JSON Schema of fleet config files (for editors)",
        description="Print the JSON Schema (draft-07) of fleet config files: the sections, their "
        "fields, types, defaults and ranges, for completion and checks while editing. The map and "
        "roadmap checks (poses clear of obstacles, references) need `fleet validate`.",
        epilog=EPILOG,
    )
    p.add_argument("--out", type=Path, metavar="FILE", help="write the schema to FILE instead of printing it")
    return p


def handle(args: argparse.Namespace) -> int:
    """Print the schema, or write it to ``args.out``; exit 2 if the file cannot be written."""
    from fleet.config.schema import json_schema_text  # the config stack only for this command

    text = json_schema_text()
    if args.out is None:
        sys.stdout.write(text)
        return EXIT_OK
    try:
        args.out.write_text(text)
    except OSError as e:
        print(f"error: cannot write {args.out}: {e.strerror or e}", file=sys.stderr)
        return EXIT_ERROR
    print(f"schema: {args.out}")
    return EXIT_OK
