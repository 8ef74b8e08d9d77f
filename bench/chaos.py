"""Chaos run: ``fleet chaos`` (:mod:`fleet.chaos.run`) with the options this bench always had.

Kills a random process of the split fleet (``fleet sim --state``, ``fleet coordinator
--state``, one ``fleet agent`` per robot) with ``kill -9`` every ``--every`` wall seconds and
restarts it, until the fleet has run ``--duration`` simulated seconds; prints the table of kills
and recovery times and exits 1 unless tasks lost, done twice, collisions and tracebacks are all
0 and no battery went below 5 %. Figures: docs/faults.md.

    python bench/chaos.py --robots 6 --duration 1800 --speed 10 --every 8 --seed 1
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fleet.cli.main import main as fleet  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", type=Path, default=ROOT / "configs" / "warehouse_patrol.yaml")
    a, rest = p.parse_known_args(argv)
    return fleet(["chaos", str(a.config), *rest])


if __name__ == "__main__":
    sys.exit(main())
