"""The one robot tree that runs every task kind (``fleet run``'s robots all run it), so a
fleet takes any task at runtime: patrol laps, go_to, picks with their dwell, inspections
(wait, spin, capture at each waypoint), and charge errands.

Without traffic management::

    Selector(memory=False) "TaskRobot /robot1"
      BatteryGuard   BatteryLow -> NavigateToPose(charger) -> Charge       (nodes.trees)
      ChargeTask     charge_now? -> HasCharger -> ReportFailure[NavigateToPose(charger), Charge]
                     -> FinishCharge
      Patrol         HasRoute -> RestartOnChange[Repeat[Recovery[FollowRoute]]]   (nodes.trees)
      Steps          HasSteps -> RestartOnChange[ReportFailure[Recovery[FollowSteps]]]
      Idle

With traffic management (``docs/traffic.md``) the driving leaves are grant followers: the
guard's and the charge task's way to the charger is ``FollowGrant(purpose=charge)``, the
patrol ``FollowGrant(count_laps)``, the steps ``FollowGrantSteps`` and the idle leaf
``FollowGrant(idle)`` (so an idle robot still moves aside when asked); no recovery
behaviours (they would leave the reserved space).

Which branch runs is what the agent put on the blackboard from the robot's order: ``route``
(patrol), ``steps`` (go_to, pick, inspection, park) or ``charge_now`` (charge); see
:mod:`nodes.blackboard` and :mod:`nodes.steps`. Priorities are re-checked every tick: a low
battery interrupts any task, which resumes where it was once charged.
"""

from __future__ import annotations

from collections.abc import Callable

import py_trees
from py_trees.behaviour import Behaviour
from py_trees.common import Status

from fleet.navigation import Clock, NavigationBackend
from fleet.robots import BatteryModel
from fleet.traffic.purpose import Purpose
from fleet.types import Mode, TreeKind
from nodes.blackboard import normalize_namespace, read_key, robot_blackboard
from nodes.conditions import HasAssignment
from nodes.leaves import Charge, Idle, NavigateToPoseAction
from nodes.recovery import RestartOnChange
from nodes.steps import FollowGrantSteps, FollowSteps, ReportFailure
from nodes.traffic import FollowGrant
from nodes.trees import battery_guard, build_tree, navigate_with_recovery, patrol_branch


class Flag(py_trees.behaviour.Behaviour):
    """SUCCESS when the robot's boolean blackboard ``key`` is true, else FAILURE."""

    wake_aware = True  # reads the blackboard only

    def __init__(self, namespace: str, key: str, *, name: str | None = None) -> None:
        super().__init__(name=name or f"Is{key.title().replace('_', '')}")
        self.key = key
        self.bb = robot_blackboard(namespace, name=self.name, keys=(key,))
        self.blackboards.append(self.bb)

    def update(self) -> Status:
        return Status.SUCCESS if bool(self.bb.get(self.key)) else Status.FAILURE


class FinishCharge(py_trees.behaviour.Behaviour):
    """The charge task is done: ``result_id = task_id``, ``result = "succeeded"``,
    ``charge_now`` cleared. SUCCESS at once; nothing to cancel."""

    wake_aware = True  # writes the blackboard only

    def __init__(self, namespace: str, *, name: str = "FinishCharge") -> None:
        super().__init__(name=name)
        self.bb = robot_blackboard(
            namespace, name=name, keys=("task_id", "result_id", "result", "charge_now")
        )
        self.blackboards.append(self.bb)

    def update(self) -> Status:
        bb = self.bb
        bb.result_id = bb.task_id
        bb.result = "succeeded"
        bb.charge_now = False
        return Status.SUCCESS


def charge_branch(
    ns: str, backend: NavigationBackend, clock: Clock, battery: BatteryModel, traffic: bool
) -> Behaviour:
    """``Sequence[charge_now?, HasCharger, ReportFailure[Sequence(memory)[to charger, Charge]],
    FinishCharge]``: a charge task sends the robot to its charger now and ends when the
    battery reaches ``battery.resume``."""
    go: Behaviour
    if traffic:
        go = FollowGrant(
            backend, clock, mode=Mode.CHARGING, purpose=Purpose.CHARGE, name="GrantToChargerTask"
        )
    else:
        go = navigate_with_recovery(
            NavigateToPoseAction(
                backend, read_key(ns, "charger"), name="ChargeTaskToCharger", mode=Mode.CHARGING
            ),
            backend,
        )
    charge = py_trees.composites.Sequence(
        "ChargeNow",
        memory=True,
        children=[go, Charge(backend, clock, battery.resume, name="ChargeTaskCharge")],
    )
    return py_trees.composites.Sequence(
        "ChargeTask",
        memory=False,
        children=[
            Flag(ns, "charge_now"),
            HasAssignment(ns, "charger", name="HasChargerTask"),
            ReportFailure(charge, ns, name="ChargeFailed"),
            FinishCharge(ns),
        ],
    )


def steps_branch(
    ns: str, backend: NavigationBackend, clock: Clock, traffic: bool, retries: int = 6
) -> Behaviour:
    """``Sequence[HasSteps, RestartOnChange(task_id, steps)[ReportFailure[...]]]`` around
    :class:`~nodes.steps.FollowSteps` (with recoveries) or, under traffic management,
    :class:`~nodes.steps.FollowGrantSteps`. RUNNING while the task runs; SUCCESS when it is
    done; FAILURE when there are no steps or the task failed (reported, steps cleared)."""
    run: Behaviour
    if traffic:
        run = FollowGrantSteps(backend, clock)
    else:
        run = navigate_with_recovery(FollowSteps(backend), backend, retries=retries, name="StepsRecovery")
    return py_trees.composites.Sequence(
        "Steps",
        memory=False,
        children=[
            HasAssignment(ns, "steps", name="HasSteps"),
            RestartOnChange("OnNewSteps", ReportFailure(run, ns, name="StepsFailed"), _watch(ns, "steps")),
        ],
    )


def _watch(ns: str, key: str) -> Callable[[], object]:
    """``() -> (task_id, <key>)``: what a branch restarts on."""
    task_id = read_key(ns, "task_id")
    value = read_key(ns, key)
    return lambda: (task_id(), value())


def task_tree(
    namespace: str,
    backend: NavigationBackend,
    clock: Clock,
    battery: BatteryModel,
    *,
    retries: int = 6,
    traffic: bool = False,
) -> Behaviour:
    """The robot tree that runs every task kind (see the module docstring); ``traffic``
    builds the variant whose driving leaves follow traffic grants."""
    ns = normalize_namespace(namespace)
    robot_blackboard(ns, name=f"{ns}-tree")
    patrol: Behaviour
    if traffic:
        guard = battery_guard(
            ns,
            backend,
            clock,
            battery,
            go_to_charger=FollowGrant(
                backend, clock, mode=Mode.CHARGING, purpose=Purpose.CHARGE, name="GrantToCharger"
            ),
        )
        patrol = py_trees.composites.Sequence(
            "Patrol",
            memory=False,
            children=[
                HasAssignment(ns, "route", name="HasRoute"),
                FollowGrant(backend, clock, mode=Mode.PATROL, count_laps=True, name="GrantPatrol"),
            ],
        )
        idle: Behaviour = FollowGrant(backend, clock, mode=Mode.IDLE, name="GrantIdle")
    else:
        guard = battery_guard(ns, backend, clock, battery)
        patrol = patrol_branch(ns, backend, retries=retries)
        idle = Idle(ns)
    return py_trees.composites.Selector(
        f"TaskRobot {ns}",
        memory=False,
        children=[
            guard,
            charge_branch(ns, backend, clock, battery, traffic),
            patrol,
            steps_branch(ns, backend, clock, traffic, retries),
            idle,
        ],
    )


def build_robot_tree(
    kind: TreeKind | str,
    namespace: str,
    backend: NavigationBackend,
    clock: Clock,
    battery: BatteryModel,
    *,
    retries: int = 6,
    traffic: bool = False,
) -> Behaviour:
    """The tree of ``kind``: ``"tasks"`` (:func:`task_tree`, every task kind), or the
    single-purpose ``"patrol"`` / ``"picking"`` trees of :func:`nodes.trees.build_tree`.
    Raises :class:`~fleet.errors.FleetError` for an unknown kind (or picking with traffic)."""
    if kind == TreeKind.TASKS:
        return task_tree(namespace, backend, clock, battery, retries=retries, traffic=traffic)
    return build_tree(kind, namespace, backend, clock, battery, retries=retries, traffic=traffic)


def build_agent_tree(
    tree_kind: str,
    tree_file: str | None,
    namespace: str,
    backend: NavigationBackend,
    clock: Clock,
    battery: BatteryModel,
    traffic: bool,
) -> Behaviour:
    """The robot's tree: the XML file's when one is given, else the built-in tree of ``tree_kind``."""
    if tree_file is not None:
        from nodes.xml_tree import load_tree

        return load_tree(tree_file, namespace, backend, clock, battery).root
    return build_robot_tree(tree_kind, namespace, backend, clock, battery, traffic=traffic)
