"""Time in ``fleet sim-ros``: simulated time follows ``--speed`` times the wall time, paced
by :class:`fleet.clock.Pacer`; a backlog the machine cannot catch up with is dropped instead
of running the world in bursts; ``--speed 0`` pauses the world. A server in this process
with a wall clock the test moves (nothing is spun, no real time is read)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from fleet.ros.env import ros_available

if ros_available() or TYPE_CHECKING:  # else every test here is skipped (conftest.py)
    from rclpy.context import Context

    from fleet.ros.nav2_server import MAX_CATCH_UP_STEPS, Nav2SimServer, build_simulator, main

WAREHOUSE = Path(__file__).resolve().parents[3] / "configs" / "warehouse_patrol.yaml"

pytestmark = pytest.mark.ros


class ManualWall:
    """A wall clock that moves only when the test says so."""

    def __init__(self) -> None:
        self.t = 1000.0

    def now(self) -> float:
        return self.t


Serve = Callable[[float], "tuple[Nav2SimServer, ManualWall]"]


@pytest.fixture()
def serve(ros_context: Context) -> Iterator[Serve]:
    """``serve(speed)``: a server of the warehouse's ``/robot1`` paced against its own
    :class:`ManualWall` (closed at the end of the test)."""
    made: list[Nav2SimServer] = []

    def make(speed: float) -> tuple[Nav2SimServer, ManualWall]:
        wall = ManualWall()
        server = Nav2SimServer(
            build_simulator(str(WAREHOUSE)),
            ["/robot1"],
            speed=speed,
            profile="lean",
            odom_hz=0,
            amcl_hz=0,
            context=ros_context,
            wall=wall,
        )
        made.append(server)
        return server, wall

    yield make
    for server in made:
        server.close()


def test_simulated_time_follows_speed_times_wall_time(serve: Serve) -> None:
    server, wall = serve(2.0)
    sim = server.sim
    t0 = sim.clock.now()
    server.step_to_wall_time()
    assert sim.clock.now() == t0  # no wall time passed: no step
    wall.t += 0.25
    server.step_to_wall_time()
    assert sim.clock.now() - t0 == pytest.approx(0.5)  # 2x
    wall.t += 0.01  # less than one step owed (0.02 simulated s): wait for more
    server.step_to_wall_time()
    assert sim.clock.now() - t0 == pytest.approx(0.5)


def test_a_backlog_it_cannot_catch_up_with_is_dropped(serve: Serve) -> None:
    server, wall = serve(1.0)
    sim = server.sim
    step = sim.params.step_s
    t0 = sim.clock.now()
    wall.t += 60.0  # the process was stalled for a minute
    server.step_to_wall_time()
    assert sim.clock.now() - t0 == pytest.approx(MAX_CATCH_UP_STEPS * step)
    server.step_to_wall_time()  # the rest was dropped: no burst
    assert sim.clock.now() - t0 == pytest.approx(MAX_CATCH_UP_STEPS * step)
    wall.t += 0.5  # paced again from there
    server.step_to_wall_time()
    assert sim.clock.now() - t0 == pytest.approx(MAX_CATCH_UP_STEPS * step + 0.5)


def test_speed_zero_pauses_the_world(serve: Serve) -> None:
    server, wall = serve(0.0)
    t0 = server.sim.clock.now()
    wall.t += 10.0
    server.step_to_wall_time()
    assert server.sim.clock.now() == t0


def test_a_bad_config_is_a_clear_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["/nonexistent/fleet.yaml"]) == 2
    assert "/nonexistent/fleet.yaml: config file does not exist" in capsys.readouterr().err
