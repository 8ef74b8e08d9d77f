"""The navigation backend conformance checker: does a backend keep the
:class:`fleet.navigation.NavigationBackend` contract?

Like Gymnasium's ``check_env``, :func:`check_backend` runs every conformance case against a
backend you bring and returns a :class:`ConformanceReport` naming each failure and its
reason. It only uses the protocol, the harness's ``advance`` and the facts of its world.

You bring a *harness factory*: a zero-argument callable returning a context manager that
yields a :class:`ConformanceHarness` (and tears everything down on exit). Each case gets a
fresh harness. A harness has

* ``backend``: the :class:`~fleet.navigation.NavigationBackend` under test, driving one robot
  that starts at ``world.start``;
* ``world``: a :class:`ConformanceWorld` naming a reachable pose, an occupied pose, an off-map
  pose, an unreachable (enclosed) pose, the free distance behind the start and the backend's
  goal-checker tolerances (:data:`fleet.testing.room.SIM_WORLD` describes the simulator's room);
* ``advance(seconds)``: let ``seconds`` of the backend's time pass. A simulated backend steps
  its simulator; a real-time backend sleeps (waits for a connection must be conditions with
  deadlines, inside the factory).

A backend that cannot offer a capability of :data:`CAPABILITIES` (e.g. SUMO vehicles cannot
reverse) declares it in ``lacks`` with the reason; the cases needing it are reported SKIPPED.

Example::

    from contextlib import contextmanager
    from fleet.testing.conformance import check_backend

    @contextmanager
    def my_harness():
        world = start_my_world()
        try:
            yield MyHarness(backend=world.backend("/robot1"), world=MY_WORLD, advance=world.run_for)
        finally:
            world.close()

    report = check_backend(my_harness)
    print(report)            # one line per case: PASSED / FAILED: reason / SKIPPED: reason
    assert report.ok
"""

from __future__ import annotations

import enum
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

from fleet.errors import FleetError
from fleet.navigation import NavigationBackend
from fleet.testing.batch_cases import BATCH_CASES
from fleet.testing.harness import (
    CAPABILITIES,
    Case,
    CaseFailed,
    ConformanceHarness,
    ConformanceWorld,
    HarnessFactory,
    case_registry,
    expect,
    finish,
    robot_pose,
    wait_for,
)
from fleet.testing.planning_cases import PLANNING_CASES
from fleet.types import (
    BackUp,
    ErrorCode,
    FollowWaypoints,
    GoalStatus,
    NavigateToPose,
    Pose2D,
    Spin,
    TaskResult,
    Wait,
    normalize_angle,
)

__all__ = [
    "CAPABILITIES",
    "CASES",
    "Case",
    "CaseResult",
    "ConformanceHarness",
    "ConformanceReport",
    "ConformanceWorld",
    "HarnessFactory",
    "Outcome",
    "check_backend",
    "expect",
    "run_case",
    "wait_for",
]


class Outcome(enum.Enum):
    """How a case ended."""

    PASSED = "passed"
    FAILED = "failed"
    SKIPPED = "skipped"


@dataclass(frozen=True)
class CaseResult:
    """The outcome of one case, with the reason for a failure or a skip."""

    name: str
    outcome: Outcome
    reason: str = ""

    @property
    def passed(self) -> bool:
        return self.outcome is Outcome.PASSED

    def __str__(self) -> str:
        tail = f": {self.reason}" if self.reason else ""
        return f"{self.outcome.value.upper():7} {self.name}{tail}"


@dataclass(frozen=True)
class ConformanceReport:
    """Every case's result, in the order of :data:`CASES`. ``ok`` when none failed."""

    results: tuple[CaseResult, ...] = field(default_factory=tuple)

    @property
    def ok(self) -> bool:
        return not self.failures

    @property
    def failures(self) -> tuple[CaseResult, ...]:
        return tuple(r for r in self.results if r.outcome is Outcome.FAILED)

    def __str__(self) -> str:
        counts = {o: sum(r.outcome is o for r in self.results) for o in Outcome}
        head = ", ".join(f"{n} {o.value}" for o, n in counts.items())
        return "\n".join([f"backend conformance: {head}", *(f"  {r}" for r in self.results)])


def run_case(factory: HarnessFactory, case: Case, lacks: Mapping[str, str] | None = None) -> CaseResult:
    """Run ``case`` on a fresh harness of ``factory``. A case needing a capability in ``lacks``
    (name -> reason) is SKIPPED; a contract violation, or any exception from the backend or
    the harness, FAILS it with the reason."""
    missing = sorted(case.requires & set(lacks or {}))
    if missing:
        reasons = "; ".join(f"lacks {m}: {(lacks or {})[m]}" for m in missing)
        return CaseResult(case.name, Outcome.SKIPPED, reasons)
    try:
        with factory() as harness:
            case.check(harness)
    except CaseFailed as e:
        return CaseResult(case.name, Outcome.FAILED, str(e))
    except Exception as e:  # noqa: BLE001 - any error of the backend is a failure to report
        return CaseResult(case.name, Outcome.FAILED, f"raised {type(e).__name__}: {e}")
    return CaseResult(case.name, Outcome.PASSED)


def check_backend(
    factory: HarnessFactory, lacks: Mapping[str, str] | None = None, cases: Iterable[Case] | None = None
) -> ConformanceReport:
    """Run every case of :data:`CASES` (or ``cases``) on fresh harnesses of ``factory`` and
    report each result. ``lacks`` maps capabilities of :data:`CAPABILITIES` the backend cannot
    offer to the reason; the cases needing them are skipped. Raises ``ValueError`` for an
    unknown capability name."""
    unknown = sorted(set(lacks or {}) - set(CAPABILITIES))
    if unknown:
        raise ValueError(
            f"check_backend: lacks: unknown capabilities {unknown} (known: {sorted(CAPABILITIES)})"
        )
    return ConformanceReport(tuple(run_case(factory, c, lacks) for c in (CASES if cases is None else cases)))


# ---------------------------------------------------------------------------------------------
# The cases
# ---------------------------------------------------------------------------------------------

_CASES, _case = case_registry()
_finish = finish
_pose = robot_pose


@_case()
def satisfies_protocol(h: ConformanceHarness) -> None:
    """The backend is a NavigationBackend with a namespace starting with '/'."""
    expect(isinstance(h.backend, NavigationBackend), f"{type(h.backend).__name__} is not a NavigationBackend")
    expect(h.backend.namespace.startswith("/"), f"namespace {h.backend.namespace!r} does not start with '/'")


@_case()
def send_goal_returns_at_once_with_unique_ids(h: ConformanceHarness) -> None:
    """send_goal returns a fresh id at once; the goal is PENDING or EXECUTING before time passes."""
    ids = [h.backend.send_goal(NavigateToPose(h.world.reachable)) for _ in range(4)]
    expect(len(set(ids)) == 4, f"goal ids are not unique: {ids}")
    status = h.backend.goal_state(ids[-1]).status
    expect(status in (GoalStatus.PENDING, GoalStatus.EXECUTING), f"the last goal is {status.value} at once")


@_case()
def navigate_to_reachable_pose_succeeds_within_tolerance(h: ConformanceHarness) -> None:
    """NavigateToPose to a reachable pose SUCCEEDS and the robot ends within the tolerances."""
    w = h.world
    state = _finish(h, h.backend.send_goal(NavigateToPose(w.reachable)), w.nav_time_s)
    expect(state.status is GoalStatus.SUCCEEDED, f"ended {state.status.value}: {state.error_msg}")
    expect(state.result is TaskResult.SUCCEEDED, f"result {state.result}")
    h.advance(1.0)  # let the robot come to rest
    pose = _pose(h)
    off = pose.distance_to(w.reachable)
    expect(off <= w.goal_tolerance + 0.05, f"ended {off:.2f} m from the goal")
    yaw = abs(normalize_angle(pose.theta - w.reachable.theta))
    expect(yaw <= w.yaw_tolerance + 0.05, f"ended {yaw:.2f} rad off the goal yaw")


def _bad_goal_aborts(h: ConformanceHarness, target: Pose2D, code: ErrorCode, limit_s: float = 10.0) -> None:
    state = _finish(h, h.backend.send_goal(NavigateToPose(target)), limit_s)
    expect(state.status is GoalStatus.ABORTED, f"ended {state.status.value}, not aborted")
    expect(state.error_code == code, f"error code {state.error_code}, not {int(code)} ({code.name})")
    expect(bool(state.error_msg), "an aborted goal must explain itself (empty error_msg)")


@_case()
def goal_off_the_map_aborts_goal_outside_map(h: ConformanceHarness) -> None:
    """A goal off the map ends ABORTED with GOAL_OUTSIDE_MAP and a message."""
    _bad_goal_aborts(h, h.world.off_map, ErrorCode.GOAL_OUTSIDE_MAP)


@_case()
def unreachable_goal_aborts_no_valid_path(h: ConformanceHarness) -> None:
    """A free but enclosed goal ends ABORTED with NO_VALID_PATH and a message (within 120 s:
    a navigator tree, as Nav2's default one, first clears costmaps and tries its recoveries)."""
    _bad_goal_aborts(h, h.world.unreachable, ErrorCode.NO_VALID_PATH, 120.0)


@_case("occupancy_map")
def goal_inside_obstacle_aborts_goal_occupied(h: ConformanceHarness) -> None:
    """A goal inside a static obstacle ends ABORTED with GOAL_OCCUPIED and a message."""
    _bad_goal_aborts(h, h.world.occupied, ErrorCode.GOAL_OCCUPIED)


@_case()
def cancel_ends_canceled_and_robot_stops(h: ConformanceHarness) -> None:
    """cancel_goal of a running goal ends it CANCELED and the robot comes to a stop."""
    b = h.backend
    gid = b.send_goal(NavigateToPose(h.world.reachable))
    h.advance(3.0)
    status = b.goal_state(gid).status
    expect(status is GoalStatus.EXECUTING, f"the goal is {status.value} after 3 s, not executing")
    b.cancel_goal(gid)
    state = _finish(h, gid, 5.0)
    expect(state.status is GoalStatus.CANCELED, f"a canceled goal ended {state.status.value}")
    h.advance(2.0)
    before = _pose(h)
    h.advance(2.0)
    moved = before.distance_to(_pose(h))
    expect(moved < 0.01, f"the robot still moved {moved:.3f} m in 2 s after the cancel")
    v = b.robot_state().linear_velocity
    expect(abs(v) < 0.01, f"linear velocity {v:.3f} m/s after the cancel")


@_case()
def new_goal_preempts_running_goal(h: ConformanceHarness) -> None:
    """A new goal preempts the running one: the old goal ends ABORTED, the new one SUCCEEDS."""
    b, w = h.backend, h.world
    first = b.send_goal(NavigateToPose(w.reachable))
    h.advance(2.0)
    back_home = b.send_goal(NavigateToPose(w.start))
    old = _finish(h, first, 5.0)
    expect(old.status is GoalStatus.ABORTED, f"the preempted goal ended {old.status.value}, not aborted")
    new = _finish(h, back_home, w.nav_time_s)
    expect(new.status is GoalStatus.SUCCEEDED, f"the new goal ended {new.status.value}: {new.error_msg}")
    off = _pose(h).distance_to(w.start)
    expect(off <= w.goal_tolerance + 0.05, f"ended {off:.2f} m from the new goal")


@_case()
def cancel_of_finished_or_unknown_goal_is_a_noop(h: ConformanceHarness) -> None:
    """Canceling a finished goal (twice) or an unknown id changes nothing."""
    b = h.backend
    gid = b.send_goal(Wait(0.5))
    state = _finish(h, gid, 5.0)
    expect(state.status is GoalStatus.SUCCEEDED, f"Wait(0.5) ended {state.status.value}")
    b.cancel_goal(gid)
    b.cancel_goal(gid)
    b.cancel_goal("/nobody#424242")
    h.advance(0.5)
    status = b.goal_state(gid).status
    expect(status is GoalStatus.SUCCEEDED, f"a finished goal became {status.value} when canceled")


@_case()
def goal_state_of_unknown_id_raises_key_error(h: ConformanceHarness) -> None:
    """goal_state of an id never issued raises KeyError."""
    try:
        h.backend.goal_state("/nobody#424242")
    except KeyError:
        return
    expect(False, "goal_state('/nobody#424242') returned instead of raising KeyError")


@_case()
def goal_state_is_a_pure_read(h: ConformanceHarness) -> None:
    """Polling goal_state many times changes nothing."""
    b = h.backend
    gid = b.send_goal(Wait(5.0))
    h.advance(0.5)
    states = {b.goal_state(gid).status for _ in range(20)}
    expect(
        states == {GoalStatus.EXECUTING}, f"20 polls of a running Wait gave {sorted(s.value for s in states)}"
    )


@_case()
def feedback_present_during_navigation(h: ConformanceHarness) -> None:
    """A navigating goal reports pose, distance and time remaining, navigation time, recoveries."""
    b = h.backend
    gid = b.send_goal(NavigateToPose(h.world.reachable))
    h.advance(2.0)
    state = b.goal_state(gid)
    expect(state.status is GoalStatus.EXECUTING, f"the goal is {state.status.value} after 2 s")
    fb = state.feedback
    expect(fb.current_pose is not None, "no current_pose in the feedback")
    expect(
        fb.distance_remaining_m is not None and fb.distance_remaining_m > 0.5, f"{fb.distance_remaining_m=}"
    )
    expect(
        fb.estimated_time_remaining_s is not None and fb.estimated_time_remaining_s > 0.0,
        f"{fb.estimated_time_remaining_s=}",
    )
    expect(fb.navigation_time_s is not None and fb.navigation_time_s > 0.0, f"{fb.navigation_time_s=}")
    expect(fb.number_of_recoveries is not None, "no number_of_recoveries in the feedback")


@_case("spin_in_place")
def spin_succeeds_and_turns_the_robot(h: ConformanceHarness) -> None:
    """Spin(pi/2) SUCCEEDS and the robot's yaw turned by pi/2."""
    yaw0 = _pose(h).theta
    state = _finish(h, h.backend.send_goal(Spin(math.pi / 2, time_allowance_s=10.0)), 12.0)
    expect(state.status is GoalStatus.SUCCEEDED, f"Spin ended {state.status.value}: {state.error_msg}")
    h.advance(1.0)
    err = abs(normalize_angle(_pose(h).theta - yaw0 - math.pi / 2))
    expect(err < 0.2, f"the robot turned {err:.2f} rad off pi/2")


@_case("reverse")
def backup_succeeds_and_moves_backwards(h: ConformanceHarness) -> None:
    """BackUp SUCCEEDS and the robot moved back by the distance."""
    start = _pose(h)
    dist = min(0.3, h.world.free_behind_m / 2)
    state = _finish(h, h.backend.send_goal(BackUp(dist, speed_mps=0.15, time_allowance_s=10.0)), 12.0)
    expect(state.status is GoalStatus.SUCCEEDED, f"BackUp ended {state.status.value}: {state.error_msg}")
    h.advance(1.0)
    end = _pose(h)
    along = (end.x - start.x) * math.cos(start.theta) + (end.y - start.y) * math.sin(start.theta)
    expect(abs(along + dist) <= 0.05, f"moved {along:.3f} m along the heading, not {-dist:.3f}")


@_case()
def wait_succeeds_after_its_duration(h: ConformanceHarness) -> None:
    """Wait(1) is EXECUTING after 0.5 s and SUCCEEDS after its duration."""
    b = h.backend
    gid = b.send_goal(Wait(1.0))
    h.advance(0.5)
    status = b.goal_state(gid).status
    expect(status is GoalStatus.EXECUTING, f"Wait(1.0) is {status.value} after 0.5 s")
    state = _finish(h, gid, 3.0)
    expect(state.status is GoalStatus.SUCCEEDED, f"Wait(1.0) ended {state.status.value}")


@_case()
def empty_follow_waypoints_aborts(h: ConformanceHarness) -> None:
    """An empty FollowWaypoints is accepted and ends ABORTED (a failed goal), as Nav2's
    waypoint follower terminates an empty waypoint list."""
    state = _finish(h, h.backend.send_goal(FollowWaypoints(())), 5.0)
    expect(state.status is GoalStatus.ABORTED, f"an empty FollowWaypoints ended {state.status.value}")
    expect(state.result is TaskResult.FAILED, f"result {state.result}")


@dataclass(frozen=True)
class _UnknownGoal:
    """Looks like a goal of an action no backend knows."""

    kind: str = "teleport"


@_case()
def unknown_goal_kind_raises_and_changes_nothing(h: ConformanceHarness) -> None:
    """send_goal of an object that is no goal of fleet.types is a programming error: it raises
    a FleetError (fleet.errors) and the running goal keeps running."""
    b = h.backend
    gid = b.send_goal(Wait(5.0))
    h.advance(0.5)
    try:
        b.send_goal(_UnknownGoal())  # type: ignore[arg-type]  # the misuse under test
    except FleetError:
        pass
    except Exception as e:  # noqa: BLE001 - the wrong kind of exception is the failure
        expect(False, f"send_goal of an unknown goal kind raised {type(e).__name__}, not a FleetError: {e}")
    else:
        expect(False, "send_goal of an unknown goal kind returned instead of raising a FleetError")
    h.advance(0.5)
    status = b.goal_state(gid).status
    expect(status is GoalStatus.EXECUTING, f"the running Wait became {status.value} after the bad send_goal")


#: Every conformance case, in the order they run.
CASES: tuple[Case, ...] = (*_CASES, *PLANNING_CASES, *BATCH_CASES)
