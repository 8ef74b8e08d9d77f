"""The fleet's side of a Nav2 robot's lifecycle: is its navigator active, and bring it up.

A Nav2 bringup (or ``fleet sim-ros``) under a robot's namespace serves ``<node>/get_state``
(``lifecycle_msgs/srv/GetState``) for each managed node and ``<manager>/manage_nodes``
(``nav2_msgs/srv/ManageLifecycleNodes``) for each lifecycle manager
(``lifecycle_manager_localization``, ``lifecycle_manager_navigation``).
:class:`LifecycleWatch` asks the navigator's state (``bt_navigator``, as
``BasicNavigator.waitUntilNav2Active`` does) without blocking: :meth:`LifecycleWatch.poll`
is called on the executor thread, sends one request at a time at most every
:data:`POLL_S` wall seconds and keeps the last answer in ``state`` (``"unknown"`` until the
first; ``"unknown"`` again when the service vanishes or a request goes unanswered for
:data:`ANSWER_S`). :meth:`LifecycleWatch.startup` sends STARTUP to every manager once (what
``BasicNavigator.lifecycleStartup`` does for the robot's managers), for robots whose Nav2 was
launched without ``autostart``; the managers' service clients exist only from its first call
(four DDS endpoints a robot that an autostarted fleet never uses).
"""

from __future__ import annotations

from collections.abc import Callable

from lifecycle_msgs.srv import GetState
from nav2_msgs.srv import ManageLifecycleNodes
from rclpy.client import Client
from rclpy.node import Node
from rclpy.task import Future

#: Nav2 Jazzy's lifecycle managers (bring-up order).
MANAGERS = ("lifecycle_manager_localization", "lifecycle_manager_navigation")
#: The node whose state says whether the robot takes navigation goals.
NAVIGATOR = "bt_navigator"
#: Wall seconds between two state requests.
POLL_S = 1.0
#: Wall seconds a state request may go unanswered before the state is ``"unknown"``.
ANSWER_S = 3.0


class LifecycleWatch:
    """The navigator's lifecycle state of one robot (see the module docstring); every method
    runs on the executor thread but :attr:`state`, which may be read from any thread."""

    def __init__(self, node: Node, seen: Callable[[str], bool] | None = None) -> None:
        self._get = node.create_client(GetState, f"{NAVIGATOR}/get_state")
        # whether the navigator's get_state is served: by default rclpy's own check (it counts
        # over the whole graph); the fleet's backends pass their graph sweep's answer
        self._seen = seen if seen is not None else lambda _name: bool(self._get.service_is_ready())
        # the managers' clients are made on the first startup(): a fleet of autostarted robots
        # never needs them, and at scale every endpoint costs discovery on both sides
        self._node = node
        self._managers: list[Client] = []
        #: ``"active"``, ``"inactive"``, ``"unconfigured"``, ``"finalized"`` or ``"unknown"``.
        self.state = "unknown"
        self._pending: Future | None = None
        self._asked_at = -1e9
        self._startup: list[Future] = []
        #: Whether :meth:`startup` sent its requests; ``startup_ok`` their answers (``None``
        #: while unanswered).
        self.startup_sent = False
        self.startup_ok: bool | None = None

    @property
    def active(self) -> bool:
        return self.state == "active"

    def poll(self, now: float) -> None:
        """Collect the last answer, ask again (``now``: wall seconds, monotonic)."""
        if self._pending is not None and self._pending.done():
            res = self._pending.result()
            self.state = str(res.current_state.label) if res is not None else "unknown"
            self._pending = None
        elif self._pending is not None and now - self._asked_at > ANSWER_S:
            self._get.remove_pending_request(self._pending)  # no answer: gone or hung
            self._pending.cancel()
            self._pending = None
            self.state = "unknown"
        if self._pending is None and now - self._asked_at >= POLL_S:
            if self._seen(f"{NAVIGATOR}/get_state"):
                self._asked_at = now
                self._pending = self._get.call_async(GetState.Request())
            else:
                self.state = "unknown"  # no server: not active
        if self._startup and all(f.done() for f in self._startup):
            self.startup_ok = all(f.result() is not None and f.result().success for f in self._startup)
            self._startup = []

    def startup(self) -> None:
        """Send STARTUP to every manager, once (nothing while a manager is not discovered;
        the first call makes the managers' clients)."""
        self.make_manager_clients()
        if self.startup_sent or not all(c.service_is_ready() for c in self._managers):
            return
        self.startup_sent = True
        req = ManageLifecycleNodes.Request(command=ManageLifecycleNodes.Request.STARTUP)
        self._startup = [c.call_async(req) for c in self._managers]

    def make_manager_clients(self) -> None:
        """Make the managers' service clients now, if not yet (:meth:`startup` does it)."""
        if not self._managers:
            self._managers = [
                self._node.create_client(ManageLifecycleNodes, f"{m}/manage_nodes") for m in MANAGERS
            ]

    def destroy(self, node: Node) -> None:
        node.destroy_client(self._get)
        for c in self._managers:
            node.destroy_client(c)
