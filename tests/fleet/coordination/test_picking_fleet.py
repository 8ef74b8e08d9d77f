"""Picking fleets: the coordinator hands out the config's pick tasks (nearest waiting pick to
each idle robot, fresh ``k-`` ids, reassignment when a robot dies, charges or is stuck,
completion from the status's ``picks_done``), and ``fleet run --tree picking`` completes picks
end to end on the simulator (real Zenoh on loopback, real trees)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from fleet.cli.main import main
from fleet.config.loader import load_config
from fleet.config.model import PickTask
from fleet.coordination.coordinator import observation_from_record, task_message
from fleet.coordination.state import RESEND_S, CoordinatorState, state_from_config
from fleet.coordination.views import CoordinatorParams, Observation, TaskOrder
from fleet.messages import StatusRecord, TaskMessage
from fleet.roadmap.graph import Roadmap
from fleet.types import Pose2D

ROOT = Path(__file__).resolve().parents[3]
PICKING = ROOT / "configs" / "warehouse_picking.yaml"


def idle(x: float, y: float = 0.0, picks_done: int = 0, battery: float = 1.0) -> Observation:
    return Observation(t=0.0, pose=Pose2D(x, y), battery=battery, mode="idle", picks_done=picks_done)


def picking(
    x: float, task_id: str | None, picks_done: int = 0, mode: str = "picking", y: float = 0.0
) -> Observation:
    return Observation(t=0.0, pose=Pose2D(x, y), mode=mode, task_id=task_id, picks_done=picks_done)


def picks(orders: list[TaskOrder]) -> dict[str, TaskOrder]:
    return {o.robot: o for o in orders if o.kind == "pick"}


def line_state(stuck_reassign_s: float = 30.0) -> CoordinatorState:
    """A 1-D roadmap 0..100 m; pick ``west`` has its shelf near x=2, ``east`` near x=98,
    ``mid`` at x=50; drops at the ends; chargers at both ends."""
    rm = Roadmap.from_config_dict(
        {
            "nodes": {"a": [0, 0], "b": [5, 0], "m": [50, 0], "c": [95, 0], "d": [100, 0]},
            "edges": [["a", "b"], ["b", "m"], ["m", "c"], ["c", "d"]],
        }
    )
    tasks = [
        PickTask("east", shelf=Pose2D(98, 0.4), drop=Pose2D(100, 0), dwell_s=5.0),
        PickTask("west", shelf=Pose2D(2, 0.4), drop=Pose2D(0, 0), dwell_s=5.0),
        PickTask("mid", shelf=Pose2D(50, 0.4), drop=Pose2D(0, 0), dwell_s=5.0),
    ]
    params = CoordinatorParams(stuck_reassign_s=stuck_reassign_s, status_timeout_s=3.0, battery_low=0.25)
    return CoordinatorState([], [Pose2D(0, 1), Pose2D(100, 1)], rm, params, picks=tasks)


def test_nearest_waiting_pick_goes_to_the_nearest_idle_robot() -> None:
    s = line_state()
    s.observe("r_east", 0.0, idle(99))
    s.observe("r_west", 0.0, idle(3))
    got = picks(s.step(0.0))
    assert got["r_west"].pick is not None and got["r_west"].pick.name == "west"
    assert got["r_east"].pick is not None and got["r_east"].pick.name == "east"
    assert s.waiting_picks == ["mid"]
    o = got["r_west"]
    assert o.task_id.startswith("k-") and o.route is None and o.poses == () and o.charger is not None
    # the order survives the bus codec with its pick
    msg = TaskMessage.from_json(task_message(o).to_json())
    assert msg.kind == "pick" and msg.task_id == o.task_id
    assert msg.pick is not None and msg.pick.name == "west"
    assert (msg.pick.shelf, msg.pick.dwell_s) == (Pose2D(2, 0.4), 5.0)
    # a robot that is not idle, or low on battery, gets nothing
    s.observe("busy", 0.0, picking(50, None, mode="charging"))
    s.observe("low", 0.0, idle(50, battery=0.27))
    assert picks(s.step(0.1)) == {}


def test_global_matching_and_one_pick_per_robot() -> None:
    # r1 (x=20) is nearer the west shelf than the east one, r2 stands on the west shelf: the
    # cheapest pair is matched first, so r2 takes west and r1 the next nearest (mid)
    s = line_state()
    s.observe("r1", 0.0, idle(20))
    s.observe("r2", 0.0, idle(2))
    got = picks(s.step(0.0))
    assert got["r2"].pick is not None and got["r2"].pick.name == "west"
    assert got["r1"].pick is not None and got["r1"].pick.name == "mid"
    assert s.waiting_picks == ["east"]


def test_completion_from_picks_done_and_ids_never_reused() -> None:
    s = line_state()
    s.observe("r1", 0.0, idle(3, picks_done=4))  # an agent that already did 4 picks
    ids: list[str] = []
    o = picks(s.step(0.0))["r1"]
    ids.append(o.task_id)
    assert o.pick is not None and o.pick.name == "west"
    # the robot reports the pick: the first record with its id sets the baseline (4)
    s.observe("r1", 1.0, picking(2, o.task_id, picks_done=4))
    s.step(1.0)
    assert s.picks_completed() == 0
    # a duplicate of the same record does not complete it
    s.observe("r1", 1.1, picking(2, o.task_id, picks_done=4))
    assert s.picks_completed() == 0
    s.observe("r1", 20.0, picking(0, o.task_id, picks_done=5))
    assert s.picks_completed() == 1 and s.done_picks == {"west"}
    # done: the robot is idle again with the id still set; it gets the next pick, a new id
    s.observe("r1", 20.1, idle(0, picks_done=5))
    for t in (20.1, 20.2, 20.3):
        for order in s.step(t):
            ids.append(order.task_id)
    assert len(ids) == 2 and ids[1] > ids[0] and ids[1].startswith("k-")
    assert s.holder["mid"] == "r1" and "west" not in s.waiting_picks
    # a late copy of the old pick's record changes nothing
    s.observe("r1", 20.4, picking(2, ids[0], picks_done=5))
    assert s.picks_completed() == 1 and len(s.pick_assignments) == 2
    assert s.picks_by_robot() == {"r1": 1}


def test_pick_of_a_dead_robot_is_reassigned_and_completed_by_another() -> None:
    s2 = line_state()
    s2.observe("a", 0.0, idle(3))
    o = picks(s2.step(0.0))["a"]
    s2.observe("a", 0.5, picking(3, o.task_id))
    s2.observe("b", 0.5, picking(10, None, mode="charging"))
    s2.step(0.5)
    s2.robot_left("a", 1.0)  # its liveliness token dropped; b is busy charging
    assert s2.waiting_picks == ["east", "west", "mid"]
    s2.observe("b", 1.2, idle(10))
    got2 = picks(s2.step(1.2))
    assert got2["b"].pick is not None and got2["b"].pick.name == "west"
    (r,) = s2.reassignments
    assert (r.route, r.from_robot, r.reason, r.to_robot) == ("west", "a", "dead", "b")
    assert r.old_task_id == o.task_id and r.new_task_id == got2["b"].task_id != o.task_id
    assert r.t == 1.0 and r.t_reassigned == 1.2
    s2.observe("b", 2.0, picking(8, got2["b"].task_id))
    s2.observe("b", 30.0, picking(1, got2["b"].task_id, picks_done=1))
    assert s2.picks_completed() == 1 and s2.done_picks == {"west"}
    # the dead robot comes back with its old id and a higher count: not counted, told to idle
    s2.observe("a", 31.0, picking(2, o.task_id, picks_done=1))
    back = s2.step(31.0)
    assert s2.picks_completed() == 1
    assert [(x.robot, x.kind) for x in back if x.robot == "a"] == [("a", "idle")]


def test_pick_of_a_charging_robot_is_reassigned() -> None:
    s = line_state()
    s.observe("a", 0.0, idle(3))
    s.observe("b", 0.0, idle(97))
    first = picks(s.step(0.0))
    ta = first["a"].task_id
    s.observe("a", 1.0, picking(3, ta))
    s.observe("b", 1.0, picking(97, first["b"].task_id))
    s.step(1.0)
    s.observe("a", 5.0, picking(2, ta, mode="charging"))
    s.observe("b", 5.0, picking(96, first["b"].task_id))
    s.observe("c", 5.0, idle(10))
    out = s.step(5.0)
    assert [(o.robot, o.kind) for o in out if o.robot == "a"] == [("a", "idle")]
    got = picks(out)
    assert got["c"].pick is not None and got["c"].pick.name == "west"
    (r,) = s.reassignments
    assert (r.route, r.from_robot, r.reason, r.to_robot) == ("west", "a", "charging", "c")
    assert s.pick_assignments[0].end_reason == "charging"
    # the charging robot gets nothing until it reports idle; then the remaining pick
    s.observe("a", 6.0, picking(1, None, mode="charging"))
    s.observe("b", 6.0, picking(96, first["b"].task_id))
    s.observe("c", 6.0, picking(8, got["c"].task_id))
    assert picks(s.step(6.0)) == {}
    s.observe("a", 7.0, idle(1))
    later = picks(s.step(7.0))
    assert later["a"].pick is not None and later["a"].pick.name == "mid"


def test_stuck_pick_is_reassigned_after_stuck_time_plus_dwell() -> None:
    s = line_state(stuck_reassign_s=10.0)
    s.observe("a", 0.0, idle(40))
    o = picks(s.step(0.0))["a"]
    assert o.pick is not None and o.pick.name == "mid"
    for t in (1.0, 5.0, 10.0, 14.0):  # standing at the shelf (dwell 5 s) is not a stall yet
        s.observe("a", t, picking(50, o.task_id))
        assert s.step(t) == []
    assert s.reassignments == []
    s.observe("a", 16.5, picking(50, o.task_id))
    out = s.step(16.5)
    assert [x.kind for x in out if x.robot == "a"] == ["idle"]
    (r,) = s.reassignments
    assert r.reason == "stuck" and r.route == "mid"


def test_unacknowledged_pick_order_is_resent() -> None:
    s = line_state()
    s.observe("a", 0.0, idle(3))
    o = picks(s.step(0.0))["a"]
    s.observe("a", 0.1, idle(3))  # the order was lost
    assert s.step(0.1) == []
    s.observe("a", RESEND_S + 0.1, idle(3))
    (again,) = s.step(RESEND_S + 0.1)
    assert again == o


def test_task_kind_chooses_routes_or_picks() -> None:
    config = load_config(PICKING)
    patrol = state_from_config(config)
    assert len(patrol.routes) == len(config.routes) and patrol.picks == {}
    pick = state_from_config(config, task_kind="picking")
    assert pick.routes == {} and list(pick.picks) == [t.name for t in config.tasks]
    assert pick.waiting_picks == [t.name for t in config.tasks]
    r = config.robots[0]
    pick.observe(r.name, 0.0, idle(r.start.x, r.start.y))
    assert {o.kind for o in pick.step(0.0)} == {"pick"}
    with pytest.raises(ValueError, match="task_kind"):
        state_from_config(config, task_kind="forklift")


def test_status_record_carries_picks_done() -> None:
    rec = StatusRecord(
        robot="robot1", ns="/robot1", t=1.0, pose=(1.0, 2.0, 0.0), battery=0.9, charging=False,
        stuck=False, bt="RUNNING", leaf="GoToShelf", mode="picking", task_id="k-0001", laps=0,
        progress=0.0, distance_m=3.0, collisions=0, seq=5, picks_done=3,
    )  # fmt: skip
    back = StatusRecord.from_json(rec.to_json())
    assert back.picks_done == 3 and observation_from_record(back).picks_done == 3
    old = rec.to_dict()
    del old["picks_done"]  # a producer that does not send the field
    assert StatusRecord.from_dict(old).picks_done == 0
    old["picks_done"] = -1
    with pytest.raises(ValueError, match="status.picks_done"):
        StatusRecord.from_dict(old)


@pytest.mark.parametrize(("traffic", "least"), [("--no-traffic", 12), ("--traffic", 4)])
def test_fleet_run_picking_completes_picks(
    tmp_path: Path, zenoh_endpoint: str, traffic: str, least: int
) -> None:
    report = tmp_path / "picking.json"
    code = main(["run", str(PICKING), "--tree", "picking", traffic, "--speed", "0", "--duration", "200",
                 "--no-live", "--endpoint", zenoh_endpoint, "--report", str(report)])  # fmt: skip
    assert code == 0
    r = json.loads(report.read_text())
    # seed 1, 200 simulated seconds: 15 picks without traffic management, 6 with it (robots
    # wait for right of way: docs/performance.md); assert with margin
    assert r["picks_completed"] >= least
    assert r["picks_assigned"] >= r["picks_completed"]
    assert r["patrols_assigned"] == 0 and r["laps_completed"] == 0
    assert r["collisions"] == 0
    assert {row["final_state"] for row in r["per_robot"]} <= {"idle", "picking", "charging", "recovery"}
