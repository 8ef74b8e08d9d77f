"""Goal dispatch: the simulator's goals, and the goal executor (:class:`sim.tasks.Task`) each
robot runs.

:class:`GoalDispatch` owns the robots (:class:`sim.robot.Robot`), the
:class:`sim.goals.GoalBook` and the tasks. It starts a goal (``send``: id, preemption,
rejection, the task), answers ``goal_state`` and ``cancel``, and each step asks the tasks that
are not handed to the path follower for their command (:meth:`GoalDispatch.control`, in the
order the robots were added) and tells tasks about their events: the motion they made, arrival
or no approach from the follower, a stuck robot. It is the :class:`sim.tasks.World` the tasks
see.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from fleet.robots import SimParams
from fleet.types import Costmap, GoalState, GoalStatus
from sim.computations import Point, compute
from sim.costmap import Costmaps
from sim.goals import STATUS_CODE, GoalBook, GoalRecord, is_computation, preempt, reject_if_invalid
from sim.planner import GridPlanner, PlanResult
from sim.robot import Robot
from sim.safety import Safety
from sim.state import FleetState
from sim.tasks import NavigateTask, Task, make_task

if TYPE_CHECKING:
    from fleet.clock import SimClock


class GoalDispatch:
    """The robots, their goals and their tasks (see the module docstring).

    ``obstacles`` returns the dynamic obstacles as rows ``(x, y, radius)`` (for
    :meth:`free_distance`); ``costmaps`` the robots' live costmaps (:mod:`sim.costmap`).
    Computation goals (:mod:`sim.computations`) run through :meth:`plan_path`,
    :meth:`segment_free` and :meth:`clear_costmaps`."""

    def __init__(
        self,
        state: FleetState,
        params: SimParams,
        planner: GridPlanner,
        clock: SimClock,
        safety: Safety,
        costmaps: Costmaps,
    ) -> None:
        self.state = state
        self.costmaps = costmaps
        self.params = params
        self.planner = planner
        self.clock = clock
        self.safety = safety
        self.obstacles = np.zeros((0, 3))
        self.goals = GoalBook()
        self.robots: dict[str, Robot] = {}
        #: robots in the order they were added (robot ``i`` is row ``i`` of the state)
        self.order: list[Robot] = []
        #: the goal executor of each robot (by robot index; absent: no goal running)
        self.tasks: dict[int, Task] = {}
        #: robots whose task gets :meth:`Task.control` calls (not following a path), by index
        self._py: dict[int, Robot] = {}
        #: each robot's latest motion goal (by robot index), for the status arrays
        self._current: dict[int, GoalRecord] = {}

    def add(self, robot: Robot) -> None:
        """Register ``robot`` (its index is the next row of the state)."""
        self.robots[robot.namespace] = robot
        self.order.append(robot)

    # -- goals ----------------------------------------------------------------------------

    def send(self, robot: Robot, goal: object) -> str:
        """Start ``goal`` on ``robot``; return its id (see :meth:`sim.simulator.Simulator.send_goal`).
        A computation goal runs at once, beside the robot's motion goal."""
        record = self.goals.open(robot.namespace, goal)
        if is_computation(record.goal):
            if not reject_if_invalid(record):
                compute(record, robot.pose, self)
            return record.goal_id
        self._track(robot, record)
        old = self.tasks.get(robot.index)
        # a FollowPath replacing a running FollowPath is a path update, as in Nav2's controller
        # server: the progress checker keeps timing (replanning cannot hide a stuck robot)
        path_update = old is not None and not old.done and old.record.kind == record.kind == "follow_path"
        if old is not None and not old.done:
            preempt(old.record, record, old.feedback())
        self._set_task(robot, None)
        if reject_if_invalid(record):
            return record.goal_id
        now = self.clock.now()
        task = make_task(record, robot, self, now)
        if not task.done:
            self._set_task(robot, task)
            s, i = self.state, robot.index
            if not path_update:
                s.px[i], s.py[i], s.pt[i] = s.x[i], s.y[i], now
        return record.goal_id

    def _track(self, robot: Robot, record: GoalRecord) -> None:
        """Make ``record`` the robot's latest motion goal in the status arrays (``g_num``,
        ``g_code`` of :class:`sim.state.FleetState`)."""
        i = robot.index
        self._current[i] = record
        self.state.g_num[i] = int(record.goal_id.rpartition("#")[2])
        self.state.g_code[i] = STATUS_CODE[record.status]
        self.state.g_nav[i] = False  # until its task is the robot's (_set_task)
        record.on_finish = self._finished

    def _finished(self, record: GoalRecord) -> None:
        i = self.robots[record.namespace].index
        if self._current.get(i) is record:
            self.state.g_code[i] = STATUS_CODE[record.status]
            self.state.g_nav[i] = False

    def goal_state(self, goal_id: str) -> GoalState:
        """Snapshot of goal ``goal_id``; ``KeyError`` for an id never issued."""
        record = self.goals.get(goal_id)
        if not record.terminal:
            task = self.tasks.get(self.robots[record.namespace].index)
            if task is not None and task.record is record:
                return record.snapshot(task.feedback())
        return record.snapshot()

    def cancel(self, goal_id: str) -> None:
        """End ``goal_id`` CANCELED and stop its task; a no-op for a finished or unknown id."""
        record = self.goals.live(goal_id)
        if record is None:
            return
        robot = self.robots[record.namespace]
        task = self.tasks.get(robot.index)
        if task is not None and task.record is record:
            record.feedback = task.feedback()
            self._set_task(robot, None)
        record.finish(GoalStatus.CANCELED, 0, "")

    def _set_task(self, robot: Robot, task: Task | None) -> None:
        i = robot.index
        if task is None:
            self.tasks.pop(i, None)
        else:
            self.tasks[i] = task
        self.state.fol[i] = False
        self.state.has_task[i] = task is not None
        self.state.drives[i] = False
        self._py.pop(i, None)
        self.state.g_nav[i] = False
        if task is not None:
            if isinstance(task, NavigateTask):
                task.start(self.clock.now())
                self.state.g_nav[i] = task.planned and self._current.get(i) is task.record
            if not self.state.fol[i]:
                self._py[i] = robot

    def _task_changed(self, robot: Robot) -> None:
        """Re-file a robot whose task ended, or started / stopped following a path."""
        task = self.tasks.get(robot.index)
        i = robot.index
        if task is None or task.done:
            self.tasks.pop(i, None)
            self.state.fol[i] = False
            self.state.has_task[i] = False
            self.state.g_nav[i] = False
            self._py.pop(i, None)
        elif self.state.fol[i]:
            self._py.pop(i, None)
        else:
            self._py[i] = robot

    # -- the step's events ----------------------------------------------------------------

    def control(self, now: float, dt: float, vd: np.ndarray, wd: np.ndarray) -> list[Robot]:
        """Write the command of every task not following a path into ``vd`` / ``wd`` (in the
        order the robots were added); return those robots (for :meth:`after_move`)."""
        s = self.state
        py_robots = [self._py[i] for i in sorted(self._py)] if self._py else []
        for robot in py_robots:
            task = self.tasks.get(robot.index)
            assert task is not None
            i = robot.index
            vd[i], wd[i] = task.control(now, dt)
            s.drives[i] = task.drives
            self._task_changed(robot)
        return py_robots

    def after_move(self, robots: list[Robot], ds: np.ndarray, dth: np.ndarray) -> None:
        """Tell the tasks of ``robots`` the distance (m) and rotation (rad) they made."""
        for robot in robots:
            task = self.tasks.get(robot.index)
            if task is not None:
                task.after_move(float(ds[robot.index]), float(dth[robot.index]))

    def path_events(self, stopped: np.ndarray, arrived: np.ndarray, now: float) -> None:
        """Tell the tasks of the robots ``stopped`` by the path follower that they arrived (or,
        where ``arrived`` is False, that their remaining path stopped shrinking)."""
        s = self.state
        for i, done in zip(stopped.tolist(), arrived.tolist(), strict=True):
            robot = self.order[i]
            task = self.tasks.get(robot.index)
            if task is None:
                continue
            if done:
                task.arrived(now)
            else:
                task.no_approach(now)
            s.drives[robot.index] = task.drives if not s.fol[robot.index] else False
            self._task_changed(robot)

    def stuck(self, i: int, now: float) -> None:
        """Robot ``i`` made no progress for ``stuck_time_s`` while trying to move."""
        robot = self.order[i]
        s = self.state
        s.stuck[i] = True
        s.pt[i] = now
        task = self.tasks.get(robot.index)
        if task is not None:
            task.on_stuck()
            self._task_changed(robot)

    # -- the Planner of the computation goals --------------------------------------------

    def plan_path(self, namespace: str, start: Point, goal: Point) -> PlanResult:
        """The robot's plan from ``start`` to ``goal`` on its global costmap, strict as Nav2's
        planner server (learned obstacles closing every way: ``NO_VALID_PATH``)."""
        return self.plan(self.robots[namespace], start, goal, strict=True)

    def segment_free(self, namespace: str, a: Point, b: Point) -> bool:
        """Whether the robot's footprint stays off static obstacles from ``a`` to ``b``."""
        return self.planner.segment_free(a, b, self.planner.footprint)

    def clear_costmaps(self, namespace: str, which: Costmap) -> None:
        """Clear the robot's learned obstacles in its ``which`` costmaps (the static map stays)."""
        self.costmaps.clear(self.robots[namespace].index, str(which))

    def abort_running(self, robot: Robot, code: int, msg: str) -> str | None:
        """End ``robot``'s running goal ABORTED with ``code`` / ``msg`` (the robot stops being
        driven by it); returns its id, ``None`` when it runs none."""
        task = self.tasks.get(robot.index)
        if task is None or task.done:
            return None
        task.abort(code, msg)
        self._set_task(robot, None)
        return task.record.goal_id

    def running_kind(self, robot: Robot) -> str | None:
        """The kind of ``robot``'s running goal (``None``: none)."""
        task = self.tasks.get(robot.index)
        return None if task is None or task.done else task.record.kind

    # -- the World of the tasks -----------------------------------------------------------

    def plan(
        self, robot: Robot, start: tuple[float, float], goal: tuple[float, float], strict: bool = False
    ) -> PlanResult:
        """See :meth:`sim.tasks.World.plan`; with ``strict``, a way closed by learned obstacles
        is ``NO_VALID_PATH`` instead of the static plan."""
        static = self.planner.plan(start, goal)
        discs = self.costmaps.discs(robot.index)
        if not discs or not static.ok:
            return static
        res = self.planner.plan_avoiding(start, goal, discs)
        return res if res.ok or strict else static

    def free_distance(
        self, robot: Robot, direction: float, lookahead: float, static: bool, heading: float | None = None
    ) -> float:
        """See :meth:`sim.safety.Safety.free_distance`."""
        return self.safety.free_distance(robot.index, direction, lookahead, static, heading, self.obstacles)

    def attach_path(
        self, robot: Robot, path: list[tuple[float, float]], vias: list[int], final_yaw: float, now: float
    ) -> None:
        """Let the vectorized follower drive ``robot`` along ``path`` (see :class:`sim.tasks.World`)."""
        self.state.attach(robot.index, path, vias, final_yaw, now)
        self._py.pop(robot.index, None)

    def detach_path(self, robot: Robot) -> None:
        """Stop following the robot's path; its task gets :meth:`Task.control` calls again."""
        self.state.detach(robot.index)
        task = self.tasks.get(robot.index)
        if task is not None and not task.done:
            self._py[robot.index] = robot

    def path_remaining(self, robot: Robot) -> float:
        """Distance (m) along the followed path to its end (0 once the position is reached)."""
        return self.state.remaining(robot.index)

    def poses_remaining(self, robot: Robot) -> int:
        """Poses of the followed path not yet passed."""
        return self.state.poses_left(robot.index)

    def path_progress(self, robot: Robot) -> tuple[float, float, float, float, int]:
        """Pose, remaining path length and poses left of ``robot`` (see :class:`sim.tasks.World`)."""
        return self.state.progress(robot.index)
