"""The task book: one record per hand-over with a fresh id, take-back and hand-over again, and
completion through the task's kind (laps for patrols, ``picks_done`` for picks). A new kind
plugs in through the Task protocol alone."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import pytest

from fleet.config.model import PickTask
from fleet.coordination.state import CoordinatorState
from fleet.coordination.tasks import PatrolRoute, Pick, Task, TaskBook
from fleet.coordination.views import Assignment, Observation, TaskOrder
from fleet.roadmap.distances import Distances
from fleet.roadmap.graph import Roadmap
from fleet.types import Mode, Pose2D, TaskKind


def roadmap() -> Roadmap:
    return Roadmap.from_config_dict(
        {"nodes": {"a": [0, 0], "b": [10, 0], "c": [20, 0]}, "edges": [["a", "b"], ["b", "c"]]}
    )


def route(rm: Roadmap, name: str = "loop") -> PatrolRoute:
    return PatrolRoute(name, rm.poses_for(["a", "b", "c"], closed=True), ("a", "b", "c"))


def status(task_id: str, laps: int = 0, picks_done: int = 0, mode: str = Mode.PATROL) -> Observation:
    return Observation(t=0.0, pose=Pose2D(0, 0), mode=mode, task_id=task_id, laps=laps, picks_done=picks_done)


def test_names_are_unique_and_entries_on_the_roadmap() -> None:
    rm = roadmap()
    book = TaskBook(Distances(rm))
    book.add(route(rm))
    with pytest.raises(ValueError, match="duplicate task name 'loop'"):
        book.add(route(rm))
    with pytest.raises(ValueError, match="'zz', not a roadmap node"):
        book.add(PatrolRoute("bad", (Pose2D(0, 0),), ("zz",)))
    assert list(book.tasks) == ["loop"] and book.waiting() == ["loop"]


def test_hand_over_take_back_hand_over_again() -> None:
    rm = roadmap()
    book = TaskBook(Distances(rm))
    book.add(route(rm))
    t1 = book.next_id("p")
    a1, handed = book.assign("loop", "r1", t1, (), 1.0)
    assert handed is None and book.holder["loop"] == "r1" and book.waiting() == []
    r = book.release(a1, 5.0, "stuck")
    assert (a1.ended, a1.end_reason) == (5.0, "stuck")
    assert book.waiting() == ["loop"] and book.pending["loop"] is r
    t2 = book.next_id("p")
    a2, handed = book.assign("loop", "r2", t2, (), 6.0)
    assert handed is r and (r.to_robot, r.new_task_id, r.t_reassigned) == ("r2", t2, 6.0)
    assert book.pending == {} and book.records == [a1, a2] and book.by_id == {t1: a1, t2: a2}
    # one counter for every prefix: ids are never reused
    assert [t1, t2, book.next_id("i"), book.next_id("k")] == ["p-0001", "p-0002", "i-0003", "k-0004"]


def test_patrol_laps_count_for_the_id_and_robot_only_and_never_decrease() -> None:
    rm = roadmap()
    book = TaskBook(Distances(rm))
    book.add(route(rm))
    a, _ = book.assign("loop", "r1", "p-0001", (), 0.0)
    assert book.record("r2", status("p-0001", laps=3), 1.0, None) is None  # another robot
    assert a.laps == 0
    assert book.record("r1", status("p-0001", laps=1), 2.0, a) is None  # a patrol never finishes
    assert (a.laps, a.t_first_lap, a.completed) == (1, 2.0, True)
    book.record("r1", status("p-0001", laps=0), 3.0, a)
    assert a.laps == 1
    book.release(a, 4.0, "charging")
    book.record("r1", status("p-0001", laps=2), 5.0, None)  # a lap driven before the news
    assert (a.laps, a.t_first_lap) == (2, 2.0)
    assert book.done == set()


def test_a_pick_completes_once_from_its_active_assignment() -> None:
    rm = roadmap()
    book = TaskBook(Distances(rm))
    book.add(Pick(PickTask("p1", shelf=Pose2D(10, 1), drop=Pose2D(0, 0))))
    a, _ = book.assign("p1", "r1", "k-0001", (), 0.0)
    assert book.record("r1", status("k-0001", picks_done=7), 1.0, a) is None  # baseline 7
    assert book.record("r1", status("k-0001", picks_done=7), 2.0, a) is None
    assert book.record("r1", status("k-0001", picks_done=8), 3.0, None) is None  # not active
    assert book.record("r1", status("k-0001", picks_done=8), 4.0, a) is a
    assert a.t_completed == 4.0 and book.done == {"p1"} and book.waiting() == []
    assert book.holder["p1"] is None


def test_entry_costs_of_routes_and_picks() -> None:
    rm = roadmap()
    dist = Distances(rm)
    book = TaskBook(dist)
    book.add(route(rm))
    book.add(Pick(PickTask("p1", shelf=Pose2D(20, 3), drop=Pose2D(0, 0))))
    idx, off, offsets = book.entry_matrix(["p1", "loop"])
    names = [dist.names[i] for i in idx[1]]
    assert names[:3] == ["a", "b", "c"] and offsets
    assert dist.names[idx[0][0]] == "c" and off[0][0] == pytest.approx(3.0)
    assert list(off[1]) == [0.0] * len(off[1])
    assert route(rm).poses_from(1)[0] == route(rm).poses[1]


@dataclass(frozen=True)
class LapsPatrol:
    """A patrol done after ``laps`` laps: a kind the next step adds, written here against the
    Task protocol only."""

    route: PatrolRoute
    laps: int

    @property
    def name(self) -> str:
        return self.route.name

    @property
    def kind(self) -> TaskKind:
        return TaskKind.PATROL

    @property
    def robot(self) -> str | None:
        return None

    @property
    def id_prefix(self) -> str:
        return "n"

    @property
    def stall_grace_s(self) -> float:
        return 0.0

    def entries(self, roadmap: Roadmap) -> Sequence[tuple[str, float]]:
        return self.route.entries(roadmap)

    def poses_from(self, entry: int) -> tuple[Pose2D, ...]:
        return self.route.poses_from(entry)

    def traffic_route(self) -> PatrolRoute | None:
        return self.route

    def record(self, a: Assignment, obs: Observation, now: float, active: bool) -> bool:
        self.route.record(a, obs, now, active)
        return active and a.laps >= self.laps

    def order(self, robot: str, a: Assignment, charger: Pose2D | None) -> TaskOrder:
        return self.route.order(robot, a, charger)


def test_a_new_kind_plugs_in_through_the_protocol() -> None:
    rm = roadmap()
    s = CoordinatorState([], [Pose2D(0, 1)], rm)
    task: Task = LapsPatrol(route(rm, "twice"), laps=2)
    s.book.add(task)
    s.observe("r1", 0.0, Observation(t=0.0, pose=Pose2D(19, 0)))
    (o,) = s.step(0.0)
    assert (o.kind, o.route, o.task_id) == (TaskKind.PATROL, "twice", "n-0001")
    assert o.poses[0] == Pose2D(20, 0, o.poses[0].theta)  # entered at its nearest waypoint
    s.observe("r1", 1.0, status("n-0001", laps=1))
    assert s.waiting_routes == [] and s.robots["r1"].assignment is not None
    s.observe("r1", 2.0, status("n-0001", laps=2))
    assert s.robots["r1"].assignment is None and s.book.done == {"twice"}
    assert s.laps_completed() == 2 and s.patrols_completed() == 1
    s.observe("r1", 3.0, Observation(t=3.0, pose=Pose2D(0, 0)))
    assert s.step(3.0) == []  # done for good: not handed out again
