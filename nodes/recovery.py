"""Recovery composites in the style of Nav2's behavior trees, for py_trees.

* :class:`RecoveryNode` (Nav2 ``RecoveryNode``): run a child; when it fails, run a recovery
  subtree and, if that succeeds, retry the child, up to ``retries`` times.
* :class:`RoundRobin` (Nav2 ``RoundRobin``): each tick continues with the child after the
  one that last finished, so successive recoveries escalate through different actions.
* :class:`RestartOnChange`: a decorator that restarts its subtree (interrupting it, so
  running goals are canceled through the normal ``terminate`` path) when a watched value
  changes, e.g. the robot's ``task_id``.
* :func:`recovery_actions`: the default recovery subtree, ``RoundRobin[Wait, BackUp, Spin]``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence

import py_trees
from py_trees.behaviour import Behaviour
from py_trees.common import Status

from fleet.navigation import NavigationBackend
from fleet.types import Mode
from nodes.leaves import BackUpAction, ClearCostmapsAction, SpinAction, WaitAction


class RecoveryNode(py_trees.composites.Composite):
    """Tick ``child``; on its FAILURE tick ``recovery``; when the recovery succeeds, retry
    ``child`` (from scratch), at most ``retries`` times.

    Returns RUNNING while the child or the recovery runs; SUCCESS when the child succeeds;
    FAILURE when the recovery fails or the child fails after ``retries`` recoveries. A
    failure and the switch to the other subtree happen in the same tick. Interrupting the
    node (``stop(INVALID)``) interrupts whichever subtree is running, so its goal is
    canceled. The retry count restarts whenever the node starts afresh.
    """

    wake_aware = True  # reads only its children's statuses

    def __init__(
        self, child: Behaviour, recovery: Behaviour, retries: int = 6, *, name: str = "Recovery"
    ) -> None:
        if retries < 0:
            raise ValueError(f"RecoveryNode needs retries >= 0, got {retries}")
        super().__init__(name, [child, recovery])
        self.retries = retries
        #: Recoveries that succeeded since the node started.
        self.retry_count = 0
        #: Recoveries started since the node was built (for status and tests).
        self.recoveries_started = 0

    @property
    def child(self) -> Behaviour:
        return self.children[0]

    @property
    def recovery(self) -> Behaviour:
        return self.children[1]

    def tick(self) -> Iterator[Behaviour]:
        if self.status != Status.RUNNING:
            self.retry_count = 0
            self.current_child = self.child
            for c in self.children:
                if c.status != Status.INVALID:
                    c.stop(Status.INVALID)
            self.initialise()
        while True:
            current = self.current_child
            assert current is not None
            yield from current.tick()
            status = current.status
            if status == Status.RUNNING:
                self.status = Status.RUNNING
                yield self
                return
            if current is self.child:
                if status == Status.SUCCESS:
                    self.feedback_message = f"succeeded after {self.retry_count} recoveries"
                    self.stop(Status.SUCCESS)
                    yield self
                    return
                if self.retry_count >= self.retries:
                    self.feedback_message = (
                        f"failed after {self.retry_count} recoveries: {current.feedback_message}"
                    )
                    self.stop(Status.FAILURE)
                    yield self
                    return
                self.recoveries_started += 1
                self.feedback_message = f"recovering ({self.retry_count + 1}/{self.retries})"
                self.current_child = self.recovery
                continue
            if status == Status.SUCCESS:
                self.retry_count += 1
                self.current_child = self.child
                continue
            self.feedback_message = f"recovery failed: {current.feedback_message}"
            self.stop(Status.FAILURE)
            yield self
            return


class RoundRobin(py_trees.composites.Composite):
    """Tick the children in turn, continuing after the one that last finished.

    On each start the node resumes with the child after the one that finished last time.
    A child's SUCCESS makes the node SUCCESS; a child's FAILURE moves on to the next child in
    the same tick; FAILURE when every child failed in a row (counted across ticks while the
    node runs, as Nav2 counts them). RUNNING while a child runs.
    Interrupting it interrupts the running child.
    """

    wake_aware = True  # reads only its children's statuses

    def __init__(self, name: str, children: Sequence[Behaviour]) -> None:
        super().__init__(name, list(children))
        self._next = 0
        self._failures = 0

    def tick(self) -> Iterator[Behaviour]:
        if not self.children:
            self.stop(Status.FAILURE)
            yield self
            return
        if self.status != Status.RUNNING:
            self.current_child = self.children[self._next % len(self.children)]
            self._failures = 0
            self.initialise()
        while True:
            current = self.current_child
            assert current is not None
            yield from current.tick()
            index = self.children.index(current)
            if current.status == Status.RUNNING:
                self.status = Status.RUNNING
                yield self
                return
            self._next = (index + 1) % len(self.children)
            if current.status == Status.SUCCESS:
                self.stop(Status.SUCCESS)
                yield self
                return
            self._failures += 1
            if self._failures >= len(self.children):
                self.stop(Status.FAILURE)
                yield self
                return
            self.current_child = self.children[self._next]


class RestartOnChange(py_trees.decorators.Decorator):
    """Restart the child when ``value()`` changes while the child is RUNNING.

    Each tick the decorator reads ``value()``; if it differs from the value of the previous
    tick and the child is RUNNING, the child is interrupted (``stop(INVALID)``, which cancels
    any goal it has outstanding) and ticked again from the start in the same tick. The
    decorator's status is the child's. ``restarts`` counts the restarts.
    """

    wake_aware = True  # watches blackboard values, which change only with orders

    def __init__(self, name: str, child: Behaviour, value: Callable[[], object]) -> None:
        super().__init__(name=name, child=child)
        self._value = value
        self._seen: object = value()
        self.restarts = 0

    def tick(self) -> Iterator[Behaviour]:
        current = self._value()
        if current != self._seen and self.decorated.status == Status.RUNNING:
            self.decorated.stop(Status.INVALID)
            self.restarts += 1
            self.feedback_message = "restarted: the watched value changed"
        self._seen = current
        yield from super().tick()

    def update(self) -> Status:
        return self.decorated.status


def recovery_actions(
    backend: NavigationBackend,
    *,
    wait_s: float = 5.0,
    backup_m: float = 0.3,
    backup_speed_mps: float = 0.15,
    spin_rad: float = math.pi / 2,
    round_robin: bool = True,
    name: str = "RecoveryActions",
) -> Behaviour:
    """The default recovery subtree, as in Nav2's default navigate trees: clear the robot's
    costmaps (learned obstacles; a backend without costmaps refuses, which is ignored), then
    Wait -> BackUp -> Spin.

    With ``round_robin`` (default) each recovery runs the next action of the cycle (a failing
    action, e.g. a BackUp with something behind the robot, moves on to the next one at once);
    otherwise the three run as a Sequence and the recovery fails if any of them fails. Every
    leaf writes ``mode = Mode.RECOVERY``.
    """
    children: list[Behaviour] = [
        WaitAction(backend, wait_s, name="RecoveryWait", mode=Mode.RECOVERY),
        BackUpAction(backend, backup_m, backup_speed_mps, name="RecoveryBackUp", mode=Mode.RECOVERY),
        SpinAction(backend, spin_rad, name="RecoverySpin", mode=Mode.RECOVERY),
    ]
    actions: Behaviour = (
        RoundRobin(f"{name}Cycle", children)
        if round_robin
        else py_trees.composites.Sequence(f"{name}Sequence", memory=True, children=children)
    )
    clear = py_trees.decorators.FailureIsSuccess(
        "ClearingActions", ClearCostmapsAction(backend, name="RecoveryClearCostmaps", mode=Mode.RECOVERY)
    )
    return py_trees.composites.Sequence(name, memory=True, children=[clear, actions])
