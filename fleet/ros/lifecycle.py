"""Nav2's lifecycle for one simulated robot: managed nodes, two lifecycle managers, and the
action servers refused while their node is not active.

Nodes (``<ns>/<name>``), managed as in Nav2 Jazzy's bringup, in the order the managers bring
them up (:data:`MANAGERS`):

* ``lifecycle_manager_localization``: ``map_server``, ``amcl``;
* ``lifecycle_manager_navigation``: ``controller_server``, ``smoother_server``,
  ``planner_server``, ``behavior_server``, ``bt_navigator``, ``waypoint_follower``.

With the ``full`` profile each is an rclpy lifecycle node (:class:`rclpy.lifecycle.LifecycleNode`:
``change_state``, ``get_state``, ``get_available_states``, ``get_available_transitions``,
``get_transition_graph``, ``transition_event``); with ``lean`` only ``<node>/get_state`` is
served (on the robot's ``nav2_sim`` node), over the same state machine semantics.

Each manager serves ``<manager>/manage_nodes`` (``nav2_msgs/srv/ManageLifecycleNodes``) as
Nav2's lifecycle manager does: STARTUP configures every node in order, then activates every
node in order; CONFIGURE and RESUME (activate) go in order; PAUSE (deactivate), CLEANUP, RESET
(deactivate, cleanup) and SHUTDOWN (deactivate, cleanup, shutdown; failures ignored) go in
reverse order. A node already in the command's state (or beyond it) is left as it is, so a
second STARTUP succeeds; a finalized node cannot come back (as in Nav2: restart the server).
A transition that fails stops the command there: the response is
``success = false``, the error is logged naming the node (``Failed to change state for node:
controller_server``) and :meth:`RobotLifecycle.health` reports it (``/diagnostics``).

While its node is not active an action server rejects goals (Nav2's "Action server is
inactive"), navigation goals also need the planner and the controller; deactivating a node
aborts its running goals. ``amcl`` inactive: no ``amcl_pose`` and no ``map -> odom``.

Failure injection (tests, demos): :meth:`RobotLifecycle.fail_next` makes a node's next
configure or activate fail; the facade maps ``sim_fault`` ``fail:<node>`` to it.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING

from lifecycle_msgs.msg import State, Transition
from lifecycle_msgs.srv import GetState
from nav2_msgs.srv import ManageLifecycleNodes
from rclpy.action.server import GoalResponse
from rclpy.context import Context
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.node import Node

if TYPE_CHECKING:
    from fleet.ros.nav2_actions import RobotActions
    from sim.simulator import Simulator

logger = logging.getLogger(__name__)

#: The lifecycle managers and their nodes, in bring-up order (Nav2 Jazzy's bringup).
MANAGERS: dict[str, tuple[str, ...]] = {
    "lifecycle_manager_localization": ("map_server", "amcl"),
    "lifecycle_manager_navigation": (
        "controller_server",
        "smoother_server",
        "planner_server",
        "behavior_server",
        "bt_navigator",
        "waypoint_follower",
    ),
}
#: Every managed node.
LIFECYCLE_NODES = tuple(n for nodes in MANAGERS.values() for n in nodes)
#: The node that serves each action.
ACTION_OWNERS = {
    "navigate_to_pose": "bt_navigator",
    "navigate_through_poses": "bt_navigator",
    "follow_waypoints": "waypoint_follower",
    "spin": "behavior_server",
    "backup": "behavior_server",
    "drive_on_heading": "behavior_server",
    "wait": "behavior_server",
    "assisted_teleop": "behavior_server",
    "follow_path": "controller_server",
    "compute_path_to_pose": "planner_server",
    "compute_path_through_poses": "planner_server",
    "smooth_path": "smoother_server",
}
#: What the navigators need besides themselves.
NAVIGATION_NEEDS = ("planner_server", "controller_server")
LABELS = {
    State.PRIMARY_STATE_UNCONFIGURED: "unconfigured",
    State.PRIMARY_STATE_INACTIVE: "inactive",
    State.PRIMARY_STATE_ACTIVE: "active",
    State.PRIMARY_STATE_FINALIZED: "finalized",
}
_LEAN_NEXT: dict[
    int, tuple[tuple[int, ...], int]
] = {  # transition id -> (from states, to state), the lifecycle state machine
    Transition.TRANSITION_CONFIGURE: ((State.PRIMARY_STATE_UNCONFIGURED,), State.PRIMARY_STATE_INACTIVE),
    Transition.TRANSITION_ACTIVATE: ((State.PRIMARY_STATE_INACTIVE,), State.PRIMARY_STATE_ACTIVE),
    Transition.TRANSITION_DEACTIVATE: ((State.PRIMARY_STATE_ACTIVE,), State.PRIMARY_STATE_INACTIVE),
    Transition.TRANSITION_CLEANUP: ((State.PRIMARY_STATE_INACTIVE,), State.PRIMARY_STATE_UNCONFIGURED),
    Transition.TRANSITION_UNCONFIGURED_SHUTDOWN: (
        (State.PRIMARY_STATE_UNCONFIGURED, State.PRIMARY_STATE_INACTIVE, State.PRIMARY_STATE_ACTIVE),
        State.PRIMARY_STATE_FINALIZED,
    ),
}
_TRANSITION_NAMES = {
    Transition.TRANSITION_CONFIGURE: "Configuring",
    Transition.TRANSITION_ACTIVATE: "Activating",
    Transition.TRANSITION_DEACTIVATE: "Deactivating",
    Transition.TRANSITION_CLEANUP: "Cleaning up",
    Transition.TRANSITION_UNCONFIGURED_SHUTDOWN: "Shutting down",
}
_NODE_ARGS = ["--ros-args", "-p", "start_type_description_service:=false"]


class ManagedNode:
    """One Nav2 node's lifecycle: an rclpy :class:`LifecycleNode` (``node`` set) or, lean, a
    plain state. ``fail`` holds transitions (ids) that fail once (failure injection)."""

    def __init__(self, name: str, namespace: str, context: Context, full: bool) -> None:
        self.name = name
        self.fail: set[int] = set()
        self._lean_state: int = int(State.PRIMARY_STATE_UNCONFIGURED)
        self.node: LifecycleNode | None = None
        if full:
            self.node = _SimLifecycleNode(self, name, namespace, context)

    @property
    def state(self) -> int:
        """The primary state id (``lifecycle_msgs/State``)."""
        if self.node is not None:
            return int(self.node._state_machine.current_state[0])
        return self._lean_state

    @property
    def label(self) -> str:
        return LABELS.get(self.state, "unknown")

    def trigger(self, transition: int) -> bool:
        """Run ``transition`` (a ``lifecycle_msgs/Transition`` id); True when the node ends in
        the transition's goal state."""
        froms, goal = _LEAN_NEXT[transition]
        if self.state not in froms:
            return False
        if self.node is not None:
            trigger: Callable[[], object] = {
                Transition.TRANSITION_CONFIGURE: self.node.trigger_configure,
                Transition.TRANSITION_ACTIVATE: self.node.trigger_activate,
                Transition.TRANSITION_DEACTIVATE: self.node.trigger_deactivate,
                Transition.TRANSITION_CLEANUP: self.node.trigger_cleanup,
                Transition.TRANSITION_UNCONFIGURED_SHUTDOWN: self.node.trigger_shutdown,
            }[transition]
            trigger()
            return bool(self.state == goal)
        if transition in self.fail:
            self.fail.discard(transition)
            return False
        self._lean_state = goal
        return True

    def outcome(self, transition: int) -> TransitionCallbackReturn:
        """The callback result of ``transition`` (failure injection consumed here)."""
        if transition in self.fail:
            self.fail.discard(transition)
            return TransitionCallbackReturn.FAILURE
        return TransitionCallbackReturn.SUCCESS

    def destroy(self) -> None:
        if self.node is not None:
            self.node.destroy_node()


class _SimLifecycleNode(LifecycleNode):
    """An rclpy lifecycle node whose transitions succeed unless a failure was injected."""

    def __init__(self, owner: ManagedNode, name: str, namespace: str, context: Context) -> None:
        super().__init__(
            name,
            namespace=namespace,
            context=context,
            start_parameter_services=False,
            enable_rosout=False,
            use_global_arguments=False,
            cli_args=_NODE_ARGS,
        )
        self._owner = owner

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._owner.outcome(Transition.TRANSITION_CONFIGURE)

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._owner.outcome(Transition.TRANSITION_ACTIVATE)


class RobotLifecycle:
    """The lifecycle of one robot's Nav2 nodes (see the module docstring).

    Args:
        node: the robot's ``nav2_sim`` node (it serves the managers, and ``get_state`` when
            lean).
        sim: the simulator (deactivating a node aborts its goals there).
        namespace: the robot's namespace.
        context: the rclpy context of the server.
        full: real rclpy lifecycle nodes (else their state behind ``get_state`` only).
        autostart: bring every node up at once (Nav2's ``autostart: true``).
    """

    def __init__(
        self, node: Node, sim: Simulator, namespace: str, context: Context, *, full: bool, autostart: bool
    ) -> None:
        self._sim = sim
        self._ns = namespace
        self.nodes = {n: ManagedNode(n, namespace, context, full) for n in LIFECYCLE_NODES}
        #: The last failure of each manager (``""``: none) and what it was doing.
        self.errors: dict[str, str] = dict.fromkeys(MANAGERS, "")
        self._actions: RobotActions | None = None
        self.services = [
            node.create_service(ManageLifecycleNodes, f"{m}/manage_nodes", self._manage_cb(m))
            for m in MANAGERS
        ]
        if not full:
            self.services += [
                node.create_service(GetState, f"{n}/get_state", self._get_state_cb(n))
                for n in LIFECYCLE_NODES
            ]
        if autostart:
            for m in MANAGERS:
                self.manage(m, ManageLifecycleNodes.Request.STARTUP)

    # -- state ---------------------------------------------------------------------------

    def active(self, name: str) -> bool:
        """Whether the node ``name`` is active (unknown names: True)."""
        n = self.nodes.get(name)
        return n is None or n.state == State.PRIMARY_STATE_ACTIVE

    def accepts(self, kind: str) -> bool:
        """Whether the action ``kind`` accepts goals: its node (and, for the navigators, the
        planner and the controller) active."""
        owner = ACTION_OWNERS.get(kind)
        if owner is None:
            return True
        if not self.active(owner):
            return False
        return kind not in ("navigate_to_pose", "navigate_through_poses") or all(
            self.active(n) for n in NAVIGATION_NEEDS
        )

    def guard(self, actions: RobotActions, kinds: Iterable[str]) -> None:
        """Make ``actions``' servers (one per kind of ``kinds``, in order) reject goals while
        :meth:`accepts` says no (and else as their own goal filter says)."""
        self._actions = actions
        for server, kind in zip(actions.servers, kinds, strict=True):
            server.register_goal_callback(self._goal_cb(kind, actions.goal_filter(kind)))

    def _goal_cb(self, kind: str, inner: Callable[..., GoalResponse]) -> Callable[[object], GoalResponse]:
        def cb(request: object) -> GoalResponse:
            if self.accepts(kind):
                return inner(request)
            logger.info("%s/%s: %s is inactive: goal rejected", self._ns, kind, ACTION_OWNERS[kind])
            return GoalResponse.REJECT

        return cb

    def fail_next(self, name: str, transition: int = Transition.TRANSITION_CONFIGURE) -> None:
        """Make node ``name``'s next ``transition`` (configure by default) fail."""
        if name not in self.nodes:
            raise KeyError(f"no lifecycle node {name!r}; nodes: {', '.join(LIFECYCLE_NODES)}")
        self.nodes[name].fail.add(transition)

    def health(self) -> list[tuple[str, int, str]]:
        """``(manager, level, message)`` per manager, as Nav2's lifecycle manager reports its
        "Nav2 Health" (levels of ``diagnostic_msgs``: 0 OK, 1 WARN, 2 ERROR)."""
        out = []
        for m, names in MANAGERS.items():
            states = {self.nodes[n].state for n in names}
            if self.errors[m]:
                out.append((m, 2, self.errors[m]))
            elif states == {State.PRIMARY_STATE_ACTIVE}:
                out.append((m, 0, "Managed nodes are active"))
            elif State.PRIMARY_STATE_FINALIZED in states:
                out.append((m, 1, "Managed nodes have been shut down"))
            elif states == {State.PRIMARY_STATE_INACTIVE}:
                out.append((m, 1, "Managed nodes are inactive"))
            else:
                out.append((m, 1, "Managed nodes are unconfigured"))
        return out

    # -- the managers ------------------------------------------------------------------------

    def manage(self, manager: str, command: int) -> bool:
        """Run a ``ManageLifecycleNodes`` ``command`` on ``manager``'s nodes; True on success."""
        req = ManageLifecycleNodes.Request
        c, a = Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_ACTIVATE
        d, u = Transition.TRANSITION_DEACTIVATE, Transition.TRANSITION_CLEANUP
        steps: dict[int, tuple[tuple[int, bool], ...]] = {
            req.STARTUP: ((c, False), (a, False)),
            req.CONFIGURE: ((c, False),),
            req.RESUME: ((a, False),),
            req.PAUSE: ((d, False),),
            req.CLEANUP: ((u, False),),
            req.RESET: ((d, False), (u, False)),
            req.SHUTDOWN: ((d, True), (u, True), (Transition.TRANSITION_UNCONFIGURED_SHUTDOWN, True)),
        }
        if command not in steps:
            logger.error("%s/%s: unknown command %d", self._ns, manager, command)
            return False
        self.errors[manager] = ""
        for transition, hard in steps[command]:
            if not self._change_all(manager, transition, hard):
                return False
        return True

    def _change_all(self, manager: str, transition: int, hard: bool) -> bool:
        """Nav2's ``changeStateForAllNodes``: configure/activate in order, the rest reversed;
        the first failure stops it (unless ``hard``: shutdown goes on)."""
        names = MANAGERS[manager]
        up = transition in (Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_ACTIVATE)
        order = names if up else names[::-1]
        _, goal = _LEAN_NEXT[transition]
        for name in order:
            node = self.nodes[name]
            st = node.state
            fin = st == State.PRIMARY_STATE_FINALIZED
            if transition == Transition.TRANSITION_UNCONFIGURED_SHUTDOWN:
                done = fin
            else:
                done = not fin and (st >= goal if up else st <= goal)
            if done:
                continue  # already there (or beyond): nothing to do
            if transition == Transition.TRANSITION_DEACTIVATE:
                self._abort_goals_of(name)
            logger.info("%s/%s: %s %s", self._ns, manager, _TRANSITION_NAMES[transition], name)
            if not node.trigger(transition) and not hard:
                msg = f"Failed to change state for node: {name}"
                self.errors[manager] = msg
                logger.error(
                    "%s/%s: %s (%s failed in state %s)",
                    self._ns,
                    manager,
                    msg,
                    _TRANSITION_NAMES[transition].lower(),
                    node.label,
                )
                return False
        return True

    def _abort_goals_of(self, name: str) -> None:
        """Abort the running goals of the actions node ``name`` serves (it is deactivated)."""
        if self._actions is None:
            return
        for served in list(self._actions.active.values()):
            if ACTION_OWNERS.get(served.kind) == name:
                self._sim.cancel_goal(served.goal_id)  # ends the ROS goal ABORTED (not asked)

    def _manage_cb(
        self, manager: str
    ) -> Callable[
        [ManageLifecycleNodes.Request, ManageLifecycleNodes.Response], ManageLifecycleNodes.Response
    ]:
        def cb(
            req: ManageLifecycleNodes.Request, resp: ManageLifecycleNodes.Response
        ) -> ManageLifecycleNodes.Response:
            resp.success = self.manage(manager, int(req.command))
            return resp

        return cb

    def _get_state_cb(self, name: str) -> Callable[[GetState.Request, GetState.Response], GetState.Response]:
        def cb(_req: GetState.Request, resp: GetState.Response) -> GetState.Response:
            node = self.nodes[name]
            resp.current_state = State(id=node.state, label=node.label)
            return resp

        return cb

    def destroy(self) -> None:
        for n in self.nodes.values():
            n.destroy()
