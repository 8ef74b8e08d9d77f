"""A ``fleet run --state DIR`` killed with ``kill -9`` and started again resumes its robots, not
only its tasks: the in-process simulator's snapshot (``DIR/sim.json``, written atomically every
half wall second) puts every robot back where it was with its battery, and the clock near the
time the fleet had reached (before, the robots started again at their start poses with the
config's batteries and the clock at 0). Real processes, real Zenoh on loopback."""

from __future__ import annotations

import signal
from pathlib import Path

from fleet_procs import PATROL, BusWatch, output, processes, spawn, wait_for
from ports import free_endpoint

from fleet.bus.session import open_session
from fleet.bus.status_bus import StatusBus
from fleet.config.loader import load_config
from fleet.messages import StatusRecord
from fleet.runtime.snapshot import SNAPSHOT_FILE, SimSnapshot, read

#: Hang guard (wall s) of each wait: a few seconds on an idle machine.
WAIT_S = 180.0
#: Simulated s the first run runs before the kill: more than a paced restart (speed 5) reaches
#: by its first progress line (5 wall s), so a line counting from the restart would show less.
RAN_S = 40.0
#: Meters a robot's saved pose must be from its start pose for the resume to show.
AWAY_M = 2.0


def _snapshot(path: Path) -> SimSnapshot | None:
    """The snapshot at ``path`` (``None``: none yet); never half a file (atomic writes), so a
    read while the run writes it must not fail."""
    return read(path, "warehouse_patrol")


def test_kill_9_of_fleet_run_resumes_robots_batteries_and_clock(tmp_path: Path) -> None:
    config = load_config(PATROL, robots=2)
    starts = {r.name: r.start for r in config.robots}
    ep, state = free_endpoint(), tmp_path / "state"
    args = ["run", str(PATROL), "--robots", "2", "--duration", "3600", "--speed", "5"]
    args += ["--no-live", "--state", str(state), "--endpoint", ep]
    path = state / SNAPSHOT_FILE
    with processes() as procs:
        first = spawn(procs, args, tmp_path / "run-1.log")

        def away() -> bool:
            snap = _snapshot(path) if path.exists() else None
            return (
                snap is not None
                and snap.t > RAN_S
                and all(
                    n in snap.robots and snap.robots[n].pose.distance_to(starts[n]) > AWAY_M for n in starts
                )
            )

        wait_for(
            away, WAIT_S, f"t > {RAN_S} s, both robots {AWAY_M} m from their start poses in {path}", step=0.2
        )
        first.send_signal(signal.SIGKILL)
        assert first.wait(timeout=WAIT_S) == -signal.SIGKILL
        before = _snapshot(path)
        assert before is not None and before.t > 0.0

        again = spawn(procs, args, tmp_path / "run-2.log")
        output(again).wait_line("resuming the simulator from", WAIT_S)
        session = open_session(ep, "client", connect_timeout_s=60.0)
        try:
            bus = BusWatch(StatusBus(session))
            seen: dict[str, StatusRecord] = {}

            def located(latest: dict[str, StatusRecord]) -> bool:
                for n, rec in latest.items():
                    if rec.pose is not None:
                        seen.setdefault(n, rec)  # the first status with a pose of each robot
                return set(starts) <= set(seen)

            bus.wait(located, WAIT_S, "both robots' first located status after the restart")
            for n, rec in seen.items():
                saved = before.robots[n]
                assert rec.pose is not None
                x, y, _ = rec.pose
                # where the snapshot left it (it may have driven a little before this status),
                # not at its start pose; its battery, not the config's
                assert abs(x - saved.pose.x) + abs(y - saved.pose.y) < AWAY_M / 2, (n, rec.pose, saved)
                assert abs(rec.battery - saved.battery) < 0.02, (n, rec.battery, saved.battery)
                assert rec.t >= before.t - 1e-6, (n, rec.t, before.t)  # the clock went on
            # and the fleet works on: both robots on tasks again (the task book resumed too)
            bus.wait(
                lambda latest: all(latest.get(n) is not None and latest[n].task_id for n in starts),
                WAIT_S,
                "both robots on tasks again",
            )
            # its progress lines count on the fleet's clock too, as its event lines do
            line = output(again).wait_line(" s sim, ", WAIT_S)
            shown = float(line.split("t=", 1)[1].split(" s sim", 1)[0])
            assert shown >= before.t - 1e-6, (line, before.t)
            bus.bus.close()
        finally:
            session.close()
