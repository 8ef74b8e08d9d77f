"""Event-driven ticking (``fleet.runtime.scheduler``): the fleet whose trees tick only when
something they read changed makes the decisions of the fleet ticked at every period.

The shipped configs run twice in one process, seeded (runs are deterministic), with
``ticking="clock"`` and ``ticking="event"``; the reports must agree robot by robot (laps,
collisions, deadlocks, charges, goals, distances) while the event-driven fleet ticks its
trees a fraction of the time. No timing is asserted; the speed is in ``bench/bench_scale.py``.
"""

from __future__ import annotations

import io
import math
import shutil
from pathlib import Path
from typing import Any

import pytest
from ports import free_endpoint
from py_trees.behaviour import Behaviour
from py_trees.common import Status

from fleet.config.loader import load_config
from fleet.errors import ConfigError
from fleet.runtime.runner import FleetRunner
from fleet.runtime.watched import wake_aware
from fleet.viz.display import NullDisplay
from fleet.wake import Wake, wake_of

CONFIGS = Path(__file__).resolve().parents[3] / "configs"

#: Report keys that are wall-clock measurements, not decisions.
WALL_KEYS = {"wall_time_s", "real_time_factor", "real_time_factor_overall", "setup_wall_s"}


def _run(
    config: str,
    duration: float,
    ticking: str,
    tree: str = "patrol",
    traffic: bool = True,
    backend: str = "sim",
) -> tuple[dict[str, Any], FleetRunner]:
    runner = FleetRunner(
        load_config(CONFIGS / config),
        duration=duration,
        speed=0,
        endpoint=free_endpoint(),
        live=False,
        display=NullDisplay(),
        ticking=ticking,
        tree_kind=tree,
        traffic=traffic,
        backend=backend,
        out=io.StringIO(),
    )
    report = runner.run().to_dict()
    return {k: v for k, v in report.items() if k not in WALL_KEYS}, runner


@pytest.mark.parametrize(
    ("config", "duration", "tree", "traffic"),
    [
        ("warehouse_patrol.yaml", 450.0, "patrol", True),  # 6 robots; charging trips from ~300 s
        ("warehouse_patrol_30.yaml", 120.0, "patrol", True),  # 30 robots, traffic management
        ("warehouse_picking.yaml", 200.0, "tasks", True),  # picks: steps, dwell waits
        ("warehouse_patrol.yaml", 300.0, "patrol", False),  # the tree with Nav2-style recoveries
    ],
)
def test_event_driven_fleet_makes_the_clocked_fleets_decisions(
    config: str, duration: float, tree: str, traffic: bool
) -> None:
    clocked, c_runner = _run(config, duration, "clock", tree, traffic)
    event, e_runner = _run(config, duration, "event", tree, traffic)
    worked = clocked["laps_completed"] + clocked["picks_completed"] + clocked["patrols_completed"]
    assert worked > 0, "nothing happened: the comparison would prove nothing"
    if config == "warehouse_patrol.yaml" and traffic:
        assert sum(r["charges"] for r in clocked["per_robot"]) > 0, "the run should include charging"
    # the bar: laps within 5 %, the same collisions and deadlocks ...
    assert math.isclose(event["laps_completed"], clocked["laps_completed"], rel_tol=0.05, abs_tol=0)
    assert (event["collisions"], event["deadlocks"]) == (clocked["collisions"], clocked["deadlocks"])
    # ... and in fact the same run: every decision and every robot's outcome
    _same_decisions(c_runner, clocked, e_runner, event)


def test_event_driven_fleet_on_sumo_makes_the_clocked_fleets_decisions() -> None:
    """The SUMO world answers the batch query by a loop over its robots: same decisions."""
    clocked, c_runner = _run("warehouse_patrol.yaml", 200.0, "clock", backend="sumo")
    event, e_runner = _run("warehouse_patrol.yaml", 200.0, "event", backend="sumo")
    assert clocked["laps_completed"] > 0
    _same_decisions(c_runner, clocked, e_runner, event)
    assert e_runner.backend_name == "sumo"


def _same_decisions(
    c_runner: FleetRunner, clocked: dict[str, Any], e_runner: FleetRunner, event: dict[str, Any]
) -> None:
    """The two reports are equal key by key; the event-driven fleet ticked far fewer trees."""
    differing = sorted(k for k in clocked if clocked[k] != event.get(k))
    assert not differing, {k: (clocked[k], event.get(k)) for k in differing[:3]}
    c_sched, e_sched = c_runner.scheduler, e_runner.scheduler
    assert c_sched is not None and e_sched is not None
    assert c_sched.tree_ticks == c_sched.periods * len(c_runner.agents)
    assert e_sched.tree_ticks * 5 < c_sched.tree_ticks  # far fewer ticks for the same decisions


class _Opaque(Behaviour):
    """A leaf that does not say what it waits for."""

    def update(self) -> Status:
        return Status.RUNNING


def test_a_tree_with_a_node_outside_the_contract_is_ticked_every_period() -> None:
    from py_trees.composites import Sequence

    assert not wake_aware(Sequence("s", memory=False, children=[_Opaque("x")]))


def test_wake_of_a_plain_backend_is_none_and_conditions_accumulate() -> None:
    assert wake_of(object()) is None
    w = Wake()
    w.battery_below(0.2)
    w.battery_below(0.3)
    w.battery_at_least(0.95)
    w.at(12.0)
    w.at(10.0)
    assert (w.below, w.at_least, w.due, w.always) == (0.3, 0.95, 10.0, False)
    w.near(1.0, 2.0, 2.5)
    w.near(3.0, 2.0, 2.5)  # only one point is kept: a second one asks for every period
    assert w.always
    w.reset()
    assert (w.below, w.due, w.near_point, w.always, w.goals) == (-math.inf, math.inf, None, False, {})


def test_unknown_tick_mode_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match="ticking"):
        FleetRunner(load_config(CONFIGS / "warehouse_patrol.yaml"), ticking="sometimes")


def test_the_configs_heartbeat_reaches_the_scheduler_and_changes_no_decision(tmp_path: Path) -> None:
    """``agent.heartbeat_s`` is a safety net: a fleet whose trees tick on change makes the same
    decisions with a heartbeat of 0.5 s as with one of an hour, ticking more trees with it."""
    runs = []
    for beat in (0.5, 3600.0):
        text = (CONFIGS / "warehouse_patrol.yaml").read_text()
        assert "\nagent:\n  tick_hz:" in text
        path = tmp_path / f"beat_{beat}.yaml"
        path.write_text(text.replace("\nagent:\n", f"\nagent:\n  heartbeat_s: {beat}\n"))
        if not (tmp_path / "maps").exists():
            shutil.copytree(CONFIGS / "maps", tmp_path / "maps")
        cfg = load_config(path)
        assert cfg.heartbeat_s == beat
        runner = FleetRunner(
            cfg, duration=60.0, speed=0, endpoint=free_endpoint(), live=False, display=NullDisplay(),
            out=io.StringIO(),
        )  # fmt: skip
        report = runner.run().to_dict()
        assert runner.scheduler is not None and runner.scheduler.heartbeat_s == beat
        decided = {k: v for k, v in report.items() if k not in WALL_KEYS | {"config"}}  # config: the path
        runs.append((decided, runner.scheduler.tree_ticks))
    (often, often_ticks), (rarely, rarely_ticks) = runs
    assert often["laps_completed"] > 0 or sum(r["distance_m"] for r in often["per_robot"]) > 0
    differing = sorted(k for k in often if often[k] != rarely.get(k))
    assert not differing, {k: (often[k], rarely.get(k)) for k in differing[:3]}
    assert often_ticks > rarely_ticks + 6 * 60  # at least one more tick per robot and heartbeat-second


def test_a_heartbeat_out_of_bounds_is_a_config_error(tmp_path: Path) -> None:
    text = (CONFIGS / "warehouse_patrol.yaml").read_text()
    path = tmp_path / "bad.yaml"
    shutil.copytree(CONFIGS / "maps", tmp_path / "maps")
    path.write_text(text.replace("\nagent:\n", "\nagent:\n  heartbeat_s: 0\n"))
    with pytest.raises(ConfigError, match="heartbeat_s"):
        load_config(path)


def test_a_period_the_scheduler_skips_still_ticks_the_tree_for_orders_grants_and_a_resume() -> None:
    """The scheduler makes no pass over the agents for waiting orders: an agent's period ticks
    its tree itself when it applies orders or a grant, or when the fleet resumes."""
    from fleet.clock import SimClock
    from fleet.messages import FleetControl, Grant, TaskMessage
    from fleet.runtime.agent import RobotAgent
    from sim.simulator import Simulator

    cfg = load_config(CONFIGS / "warehouse_patrol.yaml", robots=1)
    clock = SimClock()
    sim = Simulator(cfg.grid, cfg.sim, clock)
    spec = cfg.robots[0]
    sim.add_robot(spec)
    agent = RobotAgent(spec.namespace, sim.backend(spec.namespace), clock, None, traffic=True)

    def quiet_periods() -> list[bool]:
        ticked = []
        for _ in range(5):
            agent.period(False)
            ticked.append(agent.tree_ticked)
            sim.step()
        return ticked

    agent.period(True)  # the first state: the tree starts
    assert quiet_periods() == [False] * 5
    route = cfg.route(cfg.routes[0].name)
    agent.deliver(TaskMessage(robot=spec.name, task_id="t1", kind="patrol", route=route.name,
                              poses=cfg.route_poses(route), charger=cfg.chargers[0].pose))  # fmt: skip
    assert quiet_periods()[0] is True
    grant = Grant(
        robot=spec.name, path_id=1, horizon=0, current=None, nodes=(), poses=(), task_id="t1", seq=1
    )
    agent.deliver_grant(grant)
    assert quiet_periods()[0] is True and agent.grants_applied == 1
    agent.set_control(FleetControl(estop=False, paused=True, seq=1))
    assert quiet_periods() == [False] * 5 and agent.halted == "paused"
    agent.set_control(FleetControl(estop=False, paused=False, seq=2))
    assert quiet_periods()[0] is True and agent.halted is None
    agent.close()
