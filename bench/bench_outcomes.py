"""Fleet outcomes of a fixed matrix of seeded runs, as a user would start them.

Every run is a ``fleet run`` or ``fleet loadtest`` subprocess at ``--speed 0`` on its own
loopback port. In-process runs at ``--speed 0`` do not depend on timing, so the same code and
seeds give the same outcomes: this table is how a refactor shows that behaviour did not change
(compare two tables; only the wall-time column may differ).

    python bench/bench_outcomes.py                 # the default matrix (a few minutes)
    python bench/bench_outcomes.py --only demo6    # one row
    python bench/bench_outcomes.py --json out.json # also write the rows as JSON
"""

from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

#: name -> (command after ``fleet``, whether it needs libsumo)
MATRIX: dict[str, tuple[list[str], bool]] = {
    "demo6": (["run", "configs/warehouse_patrol.yaml", "--duration", "300", "--no-traffic"], False),
    "demo6-traffic": (["run", "configs/warehouse_patrol.yaml", "--duration", "300", "--traffic"], False),
    "demo30": (["run", "configs/warehouse_patrol_30.yaml", "--duration", "300", "--no-traffic"], False),
    "demo30-traffic": (["run", "configs/warehouse_patrol_30.yaml", "--duration", "300", "--traffic"], False),
    "picking": (
        ["run", "configs/warehouse_picking.yaml", "--tree", "picking", "--duration", "300", "--no-traffic"],
        False,
    ),
    "lt100": (["loadtest", "--robots", "100", "--duration", "120", "--no-traffic"], False),
    "lt100-traffic": (["loadtest", "--robots", "100", "--duration", "120", "--traffic"], False),
    "lt1000-traffic": (["loadtest", "--robots", "1000", "--duration", "60", "--traffic"], False),
    "sumo6": (
        ["run", "configs/warehouse_patrol.yaml", "--backend", "sumo", "--duration", "120", "--no-traffic"],
        True,
    ),
}

FIELDS = (
    "robots",
    "sim_time_s",
    "patrols_assigned",
    "patrols_completed",
    "laps_completed",
    "picks_completed",
    "collisions",
    "deadlocks",
    "reassignments",
    "mean_wait_s",
)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def run_one(args: list[str]) -> dict[str, object]:
    """Run ``fleet <args>`` and return the report's outcome fields plus ``wall_s``."""
    with tempfile.TemporaryDirectory() as tmp:
        report = Path(tmp) / "report.json"
        extra = ["--report", str(report), "--endpoint", f"tcp/127.0.0.1:{_free_port()}"]
        if args[0] == "run":
            extra += ["--speed", "0", "--no-live"]
        else:
            extra += ["--out", str(Path(tmp) / "lt")]
        cmd = [sys.executable, "-m", "fleet.cli", *args, *extra]
        t0 = time.monotonic()
        proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=3600)
        wall = time.monotonic() - t0
        if proc.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)} exited {proc.returncode}:\n{proc.stderr[-2000:]}")
        r = json.loads(report.read_text())
    out: dict[str, object] = {k: r.get(k) for k in FIELDS}
    if isinstance(out["mean_wait_s"], float):
        out["mean_wait_s"] = round(out["mean_wait_s"], 2)
    out["wall_s"] = round(wall, 1)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", nargs="+", choices=sorted(MATRIX), help="run only these rows")
    ap.add_argument("--json", type=Path, help="also write the rows as JSON here")
    ap.add_argument("--quick", action="store_true", help="only demo6 and picking (for make bench)")
    args = ap.parse_args(argv)
    names = args.only or (["demo6", "picking"] if args.quick else list(MATRIX))
    try:
        import libsumo  # noqa: F401

        have_sumo = True
    except ImportError:
        have_sumo = False
    head = f"{'run':<15}" + "".join(f"{f[:10]:>11}" for f in FIELDS) + f"{'wall_s':>8}"
    print(head)
    print("-" * len(head), flush=True)
    rows: dict[str, dict[str, object]] = {}
    for name in names:
        cmd, needs_sumo = MATRIX[name]
        if needs_sumo and not have_sumo:
            print(f"{name:<15} skipped: libsumo is not installed", flush=True)
            continue
        row = run_one(cmd)
        rows[name] = row
        cells = "".join(f"{'-' if row[f] is None else row[f]!s:>11}" for f in FIELDS)
        print(f"{name:<15}{cells}{row['wall_s']!s:>8}", flush=True)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
