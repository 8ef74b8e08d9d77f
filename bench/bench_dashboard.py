"""Benchmark of the live dashboard with many robots: a real ``fleet run`` of a generated
warehouse with ``--api`` on loopback, its dashboard open in headless Chromium (the system's
``chromium`` through selenium, ``fleet.dashboard.browser``), watched for ``--seconds``.

Prints, per fleet size, what the page measured itself (``window.fleetDashboard.stats()``):
robot updates received per second, the size of one update, the time to parse and apply one
(p50/p99/max, ms), the time to draw one frame (p50/p99/max, ms; with its rasterization unless
``--no-raster``: the page reads a pixel back after each frame), frames drawn per second (a
frame is drawn only when something moved), the gap between animation-frame callbacks
(p50/p99, ms: 16.7 is 60 Hz; long gaps mean a blocked main thread), and the share of the
page's main thread that message handling and drawing take. Sizes run one after the other in one process,
so their ratios compare on the same machine load.

    python bench/bench_dashboard.py                        # 6 and 1000 robots, 20 s each
    python bench/bench_dashboard.py --robots 1000 --seconds 30 --traffic
    python bench/bench_dashboard.py --quick --json           # 50 robots, 5 s
"""

from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from fleet.dashboard.browser import (  # noqa: E402
    BrowserUnavailable,
    counts,
    find_programs,
    headless_chromium,
    stats,
    wait_until,
)
from fleet.warehouse import generate_warehouse  # noqa: E402


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _robots_with_pose(url: str) -> int:
    with urllib.request.urlopen(url + "/api/robots", timeout=30) as r:
        return sum(1 for x in json.loads(r.read()) if x.get("pose") is not None)


# long: one measurement, start to finish, reads best in one piece
def measure(
    n: int, seconds: float, speed: float, traffic: bool, raster: bool, workdir: Path
) -> dict[str, Any]:
    cfg = generate_warehouse(workdir / f"w{n}", f"dash{n}", n)
    port = _free_port()
    url = f"http://127.0.0.1:{port}"
    log = workdir / f"fleet{n}.log"
    args = [
        sys.executable, "-m", "fleet.cli", "run", str(cfg), "--no-live", "--speed", str(speed),
        "--duration", "36000", "--endpoint", f"tcp/127.0.0.1:{_free_port()}",
        "--api", f"127.0.0.1:{port}", "--state", str(workdir / f"state{n}"),
        "--traffic" if traffic else "--no-traffic",
    ]  # fmt: skip
    t0 = time.monotonic()
    with open(log, "wb") as out:
        proc = subprocess.Popen(args, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT)
    try:

        def up() -> bool:
            if proc.poll() is not None:
                raise SystemExit(f"fleet run exited with {proc.returncode}: {log.read_text()[-3000:]}")
            return _robots_with_pose(url) == n

        wait_until(up, 600, f"the API to list {n} robots", step=0.5)
        startup = time.monotonic() - t0
        with headless_chromium() as d:
            d.get(url + "/")
            wait_until(lambda: counts(d).get("markers") == n, 300, f"{n} markers on the page", step=0.2)
            first = stats(d)["robotMessages"]
            wait_until(lambda: stats(d)["robotMessages"] >= first + 20, 300, "20 robot updates (warm-up)")
            if raster:
                d.execute_script("window.fleetDashboard.setFlush(true)")
            d.execute_script("window.fleetDashboard.resetStats()")
            time.sleep(seconds)
            s = stats(d)
    finally:
        proc.terminate()
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(30)
    wall_ms = s["since_ms"]
    handle = s["robots_msg_ms"]
    frame = s["frame_ms"]
    gap = s["frame_gap_ms"]
    raf = s["raf_gap_ms"]
    busy = ((handle["mean"] or 0) * handle["n"] + (frame["mean"] or 0) * frame["n"]) / max(wall_ms, 1)
    return {
        "robots": n,
        "traffic": traffic,
        "frame_includes_raster": raster,
        "startup_s": round(startup, 1),
        "watched_s": round(wall_ms / 1000, 1),
        "updates_per_s": round(s["robot_messages_since"] / (wall_ms / 1000), 2),
        "update_kb": round((s["robots_msg_bytes"]["mean"] or 0) / 1024, 1),
        "handle_ms": {k: _r(handle[k]) for k in ("p50", "p99", "max")},
        "frame_ms": {k: _r(frame[k]) for k in ("p50", "p99", "max")},
        "fps": round(1000 / gap["mean"], 1) if gap["mean"] else 0.0,
        "animation_frame_ms": {k: _r(raf[k]) for k in ("p50", "p99", "max")},
        "main_thread_share": round(busy, 3),
    }


def _r(v: float | None) -> float | None:
    return None if v is None else round(v, 2)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robots", default="6,1000", help="fleet sizes, comma-separated (default 6,1000)")
    ap.add_argument(
        "--seconds", type=float, default=20.0, help="wall seconds to watch each page (default 20)"
    )
    ap.add_argument("--speed", type=float, default=1.0, help="fleet run --speed (default 1: real time)")
    ap.add_argument("--traffic", action="store_true", help="traffic management on (reserved segments drawn)")
    ap.add_argument(
        "--no-raster",
        action="store_true",
        help="time only the script of a frame (default: also its rasterization, forced by reading a pixel back)",
    )
    ap.add_argument("--json", action="store_true", help="one JSON line per size")
    ap.add_argument("--quick", action="store_true", help="a small check: 50 robots for 5 s (make bench)")
    args = ap.parse_args(argv)
    if args.quick:
        args.robots, args.seconds = "50", 5.0
    sizes = [int(x) for x in args.robots.split(",") if x.strip()]
    try:
        find_programs()
    except BrowserUnavailable as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-dashboard-") as tmp:
        for n in sizes:
            r = measure(n, args.seconds, args.speed, args.traffic, not args.no_raster, Path(tmp))
            rows.append(r)
            if args.json:
                print(json.dumps(r), flush=True)
    if not args.json:
        print(
            f"{'robots':>6} {'updates/s':>9} {'update KB':>9} {'handle p50/p99/max ms':>22} "
            f"{'frame p50/p99/max ms':>21} {'fps':>5} {'rAF gap p50/p99 ms':>18} {'main thread':>11}"
        )
        for r in rows:
            h, f, a = r["handle_ms"], r["frame_ms"], r["animation_frame_ms"]
            print(
                f"{r['robots']:>6} {r['updates_per_s']:>9} {r['update_kb']:>9} "
                f"{h['p50']:>7}/{h['p99']}/{h['max']:<8} {f['p50']:>6}/{f['p99']}/{f['max']:<8} "
                f"{r['fps']:>5} {a['p50']:>9}/{a['p99']:<8} {r['main_thread_share'] * 100:>10.1f}%"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
