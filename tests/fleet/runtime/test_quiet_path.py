"""The per-period path of a robot whose tree does not tick builds its values without the frozen
dataclasses' ``__init__`` and reads its state below pass-through wrappers: the objects must be
the very ones the plain constructors and reads give, and the e-stop latch must still act on a
state read alone."""

from __future__ import annotations

import dataclasses
import io
from pathlib import Path
from typing import Any

import pytest
from ports import free_endpoint
from test_agent import CountingBus

import fleet.runtime.agent as agent_module
import fleet.runtime.status_record as status_record_module
from fleet.clock import SimClock
from fleet.config.loader import load_config
from fleet.coordination.coordinator import Coordinator, observation_from_record
from fleet.coordination.views import Observation
from fleet.diagnostics import HealthParams
from fleet.messages import StatusRecord, TaskMessage
from fleet.navigation import state_reader
from fleet.runtime.agent import RobotAgent
from fleet.runtime.goal_log import GoalLog
from fleet.runtime.latch import Latch, LatchedBackend
from fleet.runtime.runner import FleetRunner
from fleet.runtime.status_record import (
    TreeView,
    held_changed,
    observation,
    observation_of,
    status_changed,
    status_record,
)
from fleet.runtime.watched import WatchedBackend
from fleet.types import GoalStatus, NavigateToPose, Pose2D, RobotState, frozen_factory, make_pose
from fleet.viz.display import NullDisplay
from sim.simulator import Simulator
from sim.snapshots import localized_robot_state

ROOT = Path(__file__).resolve().parents[3]


def test_make_pose_is_the_pose_the_dataclass_builds() -> None:
    fast, plain = make_pose(1.5, -2.0, 0.25), Pose2D(1.5, -2.0, 0.25)
    assert fast == plain and hash(fast) == hash(plain) and type(fast) is Pose2D
    assert list(vars(fast).items()) == list(vars(plain).items())  # same fields, same order
    assert make_pose(3.0, 4.0) == Pose2D(3.0, 4.0)  # theta defaults to 0
    with pytest.raises(dataclasses.FrozenInstanceError):
        fast.x = 0.0  # type: ignore[misc]  # still frozen
    assert dataclasses.replace(fast, theta=1.0) == Pose2D(1.5, -2.0, 1.0)


@pytest.mark.parametrize("pose", [(2.0, 3.0, 0.5), None])
def test_observation_from_record_is_the_dataclass_observation(
    pose: tuple[float, float, float] | None,
) -> None:
    rec = StatusRecord(
        robot="robot7", ns="/robot7", t=12.5, pose=pose, battery=0.4, charging=False, stuck=True,
        bt="RUNNING", leaf="Drive", mode="patrol", task_id="p3", laps=2, progress=0.3, distance_m=8.0,
        collisions=0, seq=9, picks_done=1, result_id="r1", result="done", steps_done=3,
    )  # fmt: skip
    obs = observation_from_record(rec)
    plain = Observation(
        t=12.5, pose=None if pose is None else Pose2D(*pose), battery=0.4, mode="patrol", stuck=True,
        task_id="p3", laps=2, picks_done=1, result_id="r1", result="done", steps_done=3,
    )  # fmt: skip
    assert obs == plain and type(obs) is Observation
    assert list(vars(obs).items()) == list(vars(plain).items())
    assert frozen_factory(Observation)(t=1.0, pose=None) == Observation(t=1.0, pose=None)  # defaults filled


def test_state_read_below_the_wrappers_is_the_robot_state_and_the_latch_still_cancels() -> None:
    cfg = load_config(ROOT / "configs" / "warehouse_patrol.yaml", robots=1)
    sim = Simulator(cfg.grid, cfg.sim, SimClock())
    spec = cfg.robots[0]
    sim.add_robot(spec)
    latch = Latch()
    backend = LatchedBackend(GoalLog(sim.backend(spec.namespace), sim.clock, 1.0), latch)
    gid = backend.send_goal(NavigateToPose(Pose2D(2.5, 14.0, 1.57)))
    for _ in range(20):
        sim.step()
    assert state_reader(backend)() == backend.robot_state() == sim.robot_state(spec.namespace)
    moving = backend.robot_state()
    assert moving.linear_velocity != 0 or moving.angular_velocity != 0  # a robot on its way
    latch.set(True)
    backend.robot_state()  # a state read alone applies the latch: the goal it let through ends
    assert sim.goal_state(gid).status is GoalStatus.CANCELED


def test_an_in_process_coordinator_reads_every_record_as_it_would_from_the_record() -> None:
    """The agents hand the in-process coordinator an Observation built from the state and tree
    they read; over a run with laps and traffic management it is, tick by tick, the Observation
    the coordinator would make of the record."""
    runner = FleetRunner(
        load_config(ROOT / "configs" / "warehouse_patrol.yaml"),
        duration=120.0,
        speed=0,
        endpoint=free_endpoint(),
        live=False,
        display=NullDisplay(),
        out=io.StringIO(),
    )
    pairs: list[tuple[Observation, StatusRecord]] = []
    real = Coordinator.feed_observations

    def feed(coordinator: Coordinator, items: list[tuple[str, Observation]]) -> None:
        # one call per period, before the cycle: each agent's record is still the period's
        assert len({robot for robot, _ in items}) == len(items)
        for robot, obs in items:
            agent = next(a for a in runner.agents if a.name == robot)
            assert agent.last_status is not None and agent.last_status.robot == robot
            pairs.append((obs, agent.last_status))
        real(coordinator, items)

    Coordinator.feed_observations = feed  # type: ignore[method-assign]
    try:
        report = runner.run()
    finally:
        Coordinator.feed_observations = real  # type: ignore[method-assign]
    assert report.laps_completed > 0 and len(pairs) >= 6 * 120 * runner.config.tick_hz * 0.9
    assert {o.mode for o, _ in pairs} >= {"patrol"}
    for obs, rec in pairs:
        assert obs == observation_from_record(rec), rec.robot


def test_a_localized_robot_state_is_the_dataclass_state() -> None:
    pose = Pose2D(1.0, 2.0, 0.5)
    fast = localized_robot_state(pose, 0.4, -0.1, 0.8, True, False, 12.5, 2, False, "bumper")
    plain = RobotState(
        pose=pose, linear_velocity=0.4, angular_velocity=-0.1, battery=0.8, charging=True, stuck=False,
        distance_m=12.5, collisions=2, navigation_ready=False, safety_stop="bumper",
    )  # fmt: skip
    assert fast == plain and type(fast) is RobotState
    assert list(vars(fast).items()) == list(
        vars(plain).items()
    )  # localized, pose age, battery known: defaults


def test_observation_of_is_the_observation_of_the_record() -> None:
    view = TreeView(
        bt="RUNNING", leaf="Drive", mode="patrol", task_id="p3", laps=2, progress=0.3, picks_done=1,
        result_id="r1", result="done", steps_done=3,
    )  # fmt: skip
    for pose in (Pose2D(2.0, 3.0, 0.5), None):
        rec = StatusRecord(
            robot="robot7", ns="/robot7", t=12.5, pose=None if pose is None else pose.as_tuple(), battery=0.4,
            charging=True, stuck=False, bt=view.bt, leaf=view.leaf, mode=view.mode, task_id=view.task_id,
            laps=view.laps, progress=view.progress, distance_m=8.0, collisions=0, seq=9,
            picks_done=view.picks_done, result_id=view.result_id, result=view.result, steps_done=view.steps_done,
        )  # fmt: skip
        fast = observation_of(12.5, pose, 0.4, False, True, view)
        plain = observation_from_record(rec)
        assert fast == plain == observation(rec, pose, view) and type(fast) is Observation
        assert list(vars(fast).items()) == list(vars(plain).items())  # same fields, same order


def test_a_period_that_publishes_nothing_builds_no_record_and_holds_the_one_tick_returns(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Two agents of the same robot on two identical simulators, one ticked with ``tick()``
    (a record every period), one with ``period()``: the second builds a record only to
    publish it (1 period in 5 at 2 Hz) or when ``last_status`` is read, and each is the very
    record the first returned, counters included as they stood at that period."""
    cfg = load_config(ROOT / "configs" / "warehouse_patrol.yaml", robots=2)
    built: list[StatusRecord] = []
    real = agent_module.status_record

    def counting(*args: Any) -> StatusRecord:
        rec = real(*args)
        built.append(rec)
        return rec

    monkeypatch.setattr(agent_module, "status_record", counting)
    pairs = []
    for _ in range(2):
        clock = SimClock()
        sim = Simulator(cfg.grid, cfg.sim, clock)
        for r in cfg.robots:
            sim.add_robot(r)
        spec = cfg.robots[0]
        bus = CountingBus()
        agent = RobotAgent(spec.namespace, sim.backend(spec.namespace), clock, bus, status_hz=2.0)
        agent.apply(
            TaskMessage(
                robot=spec.name, task_id="t1", kind="patrol", route="aisles_1_2",
                poses=cfg.route_poses(cfg.route("aisles_1_2")), charger=cfg.chargers[0].pose,
            )
        )  # fmt: skip
        pairs.append((agent, sim, bus))
    (eager, sim_a, bus_a), (lazy, sim_b, bus_b) = pairs
    records, read = [], []
    for k in range(100):
        built.clear()
        records.append(eager.tick())
        assert len(built) == 1  # tick() returns the record: built every period
        built.clear()
        lazy.period()
        assert len(built) == (1 if k % 5 == 0 else 0), k  # only the published ones
        if k % 7 == 3:
            bus_b.malformed = bus_a.malformed = k  # counted after the period: not in its record
            read.append((k, lazy.last_status))
            assert lazy.last_status is read[-1][1]  # built once
        for _ in range(round(0.1 / cfg.sim.step_s)):
            sim_a.step()
            sim_b.step()
    assert lazy.last_status == records[-1]
    assert [r for _, r in read] == [records[k] for k, _ in read]
    assert any(records[k].pose != records[0].pose for k, _ in read)  # the robot drove
    assert bus_b.statuses == bus_a.statuses and len(bus_a.statuses) == 20
    eager.close()
    lazy.close()


def _client_view(agent: RobotAgent) -> TreeView:
    """The tree view read through the agent's blackboard client (the reference)."""
    bb = agent.bb
    task_id = bb.task_id
    return TreeView(
        bt=agent.root.status.name, leaf=str(bb.active_leaf or ""), mode=str(bb.mode), task_id=task_id,
        laps=int(bb.laps) if bb.lap_task_id is not None and bb.lap_task_id == task_id else 0,
        progress=float(bb.route_progress or 0.0), picks_done=int(bb.picks_done or 0), result_id=bb.result_id,
        result=str(bb.result or ""),
        steps_done=int(bb.step_index) if bb.steps_task_id is not None and bb.steps_task_id == task_id else 0,
    )  # fmt: skip


@pytest.mark.parametrize(
    ("config", "tree"), [("warehouse_patrol.yaml", "patrol"), ("warehouse_picking.yaml", "tasks")]
)
def test_the_tree_view_read_from_the_store_is_the_clients_every_period(config: str, tree: str) -> None:
    """Over runs with laps, picks and steps, the view read from the blackboard store equals,
    after every period of every robot, the view read through the agent's blackboard client."""
    runner = FleetRunner(
        load_config(ROOT / "configs" / config), duration=150.0, speed=0, endpoint=free_endpoint(), live=False,
        display=NullDisplay(), out=io.StringIO(), tree_kind=tree,
    )  # fmt: skip
    seen: set[tuple[str, int, int]] = set()

    def compare(now: float, r: FleetRunner) -> None:
        for a in r.agents:
            view = a._tree_view()
            assert view == _client_view(a), (a.name, now)
            seen.add((view.mode, view.laps, view.steps_done))

    runner.observers.append(compare)
    report = runner.run()
    assert report.laps_completed + report.picks_completed > 0
    assert any(laps or steps for _, laps, steps in seen) and len({m for m, _, _ in seen}) > 1


@pytest.mark.parametrize(
    ("config", "tree"), [("warehouse_patrol.yaml", "patrol"), ("warehouse_picking.yaml", "tasks")]
)
def test_a_tree_reads_the_state_its_agent_read_in_the_period_and_afresh_after_a_command(
    config: str, tree: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """During a tree tick the robot state the agent read is the state a read would give, until
    the tree sends or cancels a goal: every read answered from it is checked against a fresh
    read, over runs with laps, picks, grants and charging."""
    answered, fresh = [0], [0]
    real = WatchedBackend.robot_state

    def checked(self: WatchedBackend) -> RobotState:
        got = real(self)
        if self.held is not None:
            assert got is self.held and got == self.inner.robot_state()
            answered[0] += 1
        else:
            fresh[0] += 1
        return got

    monkeypatch.setattr(WatchedBackend, "robot_state", checked)
    runner = FleetRunner(
        load_config(ROOT / "configs" / config), duration=150.0, speed=0, endpoint=free_endpoint(), live=False,
        display=NullDisplay(), out=io.StringIO(), tree_kind=tree,
    )  # fmt: skip
    report = runner.run()
    assert report.laps_completed + report.picks_completed > 0
    assert answered[0] > 100 and fresh[0] > 0  # both paths ran: reads after a command are fresh


def test_the_change_test_on_held_values_is_the_records_change_test(monkeypatch: pytest.MonkeyPatch) -> None:
    """Publishing on change decides from the held values (no record built): over a 150 s patrol
    with charging, every decision equals :func:`status_changed` of the two records, and both
    answers occur (robots standing and driving)."""
    real = status_record_module.held_changed
    answers: list[bool] = []

    def checked(old: Any, new: Any, params: Any) -> bool:
        got = real(old, new, params)
        want = status_changed(status_record("r", "/r", old, params), status_record("r", "/r", new, params))
        assert got == want, (old, new)
        answers.append(got)
        return got

    monkeypatch.setattr(agent_module, "held_changed", checked)
    cfg = load_config(ROOT / "configs" / "warehouse_patrol.yaml")
    cfg.tick_hz, cfg.status_hz, cfg.status_max_period_s = 10.0, 2.0, 5.0
    runner = FleetRunner(
        cfg, duration=150.0, speed=0, endpoint=free_endpoint(), live=False, display=NullDisplay(),
        out=io.StringIO(),
    )  # fmt: skip
    report = runner.run()
    assert report.laps_completed > 0
    assert answers.count(True) > 50 and answers.count(False) > 50


def test_the_change_test_on_held_values_sees_every_field() -> None:
    """A change of any field the record's test reads is a change on the held values too, with
    the tree view the same object or a new one; ``t`` and ``seq`` alone are not."""
    h = HealthParams(battery_low=0.2)
    st = localized_robot_state(make_pose(1.0, 2.0, 0.5), 0.0, 0.0, 0.8, False, False, 3.0, 0, True, "")
    view = TreeView("RUNNING", "Drive", "patrol", "p1", 1, 0.3, 0, None, "", 0)
    base = (st, view, 1.0, 1, (1, 2), 3, 0, 0, "", False)
    cases: list[tuple[Any, ...]] = [
        (dataclasses.replace(st, pose=make_pose(1.06, 2.0, 0.5)),),
        (dataclasses.replace(st, pose=make_pose(1.0, 2.0, 0.56)),),
        (dataclasses.replace(st, pose=None),),
        (dataclasses.replace(st, battery=0.79),),
        (dataclasses.replace(st, battery=0.1),),  # below battery_low: health changes
        (dataclasses.replace(st, distance_m=3.06),),
        (dataclasses.replace(st, charging=True),),
        (dataclasses.replace(st, stuck=True),),
        (dataclasses.replace(st, collisions=1),),
        (dataclasses.replace(st, localized=False),),
        (st, view._replace(progress=0.32)),
        (st, view._replace(mode="charging")),
        (st, view._replace(task_id="p2")),
        (st, view._replace(leaf="Wait")),
        (st, view._replace(laps=2)),
        (st, view._replace(result="failed")),
        (st, view, 1.0, 1, (1, 3)),
        (st, view, 1.0, 1, (1, 2), 4),
        (st, view, 1.0, 1, (1, 2), 3, 1),
        (st, view, 1.0, 1, (1, 2), 3, 0, 1),
        (st, view, 1.0, 1, (1, 2), 3, 0, 0, "", True),
    ]
    small = (
        dataclasses.replace(st, pose=make_pose(1.04, 2.0, 0.54), battery=0.796),
        view._replace(progress=0.305),
    )
    same = [small, (st, view, 9.0, 7), (st, view, 1.0, 1, (1, 2), 3, 0, 0, "too close")]  # a healthy state's
    # diagnostics do not read the watchdog's reason (its mode says it)
    for change in [*cases, *same]:
        new = (*change, *base[len(change) :])
        want = status_changed(status_record("r", "/r", base, h), status_record("r", "/r", new, h))  # type: ignore[arg-type]
        assert held_changed(base, new, h) == want, change  # type: ignore[arg-type]
        assert want == (change not in same), change
