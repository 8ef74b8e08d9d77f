#!/usr/bin/env python3
"""Check that interfaces/nav2_msgs (and geographic_msgs) define every type field for field as
an upstream source tree does: same field names, types, order, default values and constants
(what the RIHS01 type hash and the wire format depend on). Comments are ignored.

Usage: python tools/check_nav2_interfaces.py NAV2_MSGS_DIR [GEOGRAPHIC_MSGS_DIR]
(e.g. a checkout of Nav2's jazzy branch: navigation2/nav2_msgs). Exit 0 when all match.
"""

from __future__ import annotations

import sys
from pathlib import Path

from rosidl_adapter.parser import parse_action_string, parse_message_string, parse_service_string

ROOT = Path(__file__).resolve().parent.parent


def _msg_sig(spec) -> tuple:  # type: ignore[no-untyped-def]
    fields = tuple((str(f.type), f.name, f.default_value) for f in spec.fields)
    consts = tuple((c.type, c.name, c.value) for c in spec.constants)
    return fields, consts


def signature(pkg: str, path: Path) -> tuple:
    text = path.read_text()
    name = path.stem
    if path.suffix == ".msg":
        return _msg_sig(parse_message_string(pkg, name, text))
    if path.suffix == ".srv":
        s = parse_service_string(pkg, name, text)
        return _msg_sig(s.request), _msg_sig(s.response)
    a = parse_action_string(pkg, name, text)
    return _msg_sig(a.goal), _msg_sig(a.result), _msg_sig(a.feedback)


def check(pkg: str, ours: Path, upstream: Path) -> int:
    bad = 0
    for f in sorted(p for p in ours.rglob("*") if p.suffix in (".msg", ".srv", ".action")):
        rel = f.relative_to(ours)
        up = upstream / rel
        if not up.exists():
            print(f"MISSING upstream {pkg}/{rel}")
            bad += 1
        elif signature(pkg, f) != signature(pkg, up):
            print(f"DIFFERS {pkg}/{rel}")
            bad += 1
        else:
            print(f"ok      {pkg}/{rel}")
    return bad


def main(argv: list[str]) -> int:
    if not argv:
        print(__doc__)
        return 2
    bad = check("nav2_msgs", ROOT / "interfaces" / "nav2_msgs", Path(argv[0]))
    if len(argv) > 1:
        bad += check("geographic_msgs", ROOT / "interfaces" / "geographic_msgs", Path(argv[1]))
    print(f"{bad} mismatches")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
