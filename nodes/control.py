"""BehaviorTree.CPP and Nav2 control nodes and decorators that py_trees lacks, as py_trees
composites and decorators, so a tree loaded from XML keeps the semantics its author expects.

Composites: :class:`PipelineSequence` (Nav2), :class:`SequenceWithMemory`,
:class:`ParallelCount` (BT.CPP ``Parallel``), :class:`IfThenElse`, :class:`WhileDoElse`.
Decorators timed by the injected clock (never the wall clock): :class:`RateController`
(Nav2), :class:`TimeoutDecorator` (BT.CPP ``Timeout``), :class:`DelayDecorator` (``Delay``),
and :class:`RunOnce`, :class:`SingleTrigger`, :class:`DistanceController`,
:class:`SpeedController`, :class:`GoalUpdatedController` (Nav2). Nav2's ``RecoveryNode`` and
``RoundRobin`` are :mod:`nodes.recovery`'s.

Halting follows BehaviorTree.CPP: a node that stops a child which is RUNNING interrupts it
(``stop(INVALID)``: an action leaf cancels its goal); children that already finished are only
reset. BehaviorTree.CPP's ``SKIPPED`` does not exist in py_trees: a skipped ``RunOnce``
reports SUCCESS.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence

import py_trees
from py_trees.behaviour import Behaviour
from py_trees.common import Status

from fleet.navigation import Clock


def halt_running(children: Sequence[Behaviour]) -> None:
    """Interrupt every child that is RUNNING (its goal is canceled) and reset the others."""
    for c in children:
        if c.status != Status.INVALID:
            c.stop(Status.INVALID)


class PipelineSequence(py_trees.composites.Composite):
    """Nav2's ``PipelineSequence``: tick the children in order; a child that returned RUNNING
    before a later child started is ticked again every tick while the later ones run (e.g.
    replanning under a RateController while FollowPath drives). FAILURE of any child halts all
    and fails; SUCCESS of the last child halts all and succeeds; otherwise RUNNING."""

    def __init__(self, name: str, children: Sequence[Behaviour]) -> None:
        super().__init__(name, list(children))
        self._last = 0

    def tick(self) -> Iterator[Behaviour]:
        if self.status != Status.RUNNING:
            self._last = 0
            halt_running(self.children)
            self.initialise()
        for i, child in enumerate(self.children):
            yield from child.tick()
            if child.status == Status.FAILURE:
                yield from self._end(Status.FAILURE)
                return
            if child.status == Status.RUNNING and i >= self._last:
                self._last = i
                self.current_child = child
                self.status = Status.RUNNING
                yield self
                return
        yield from self._end(Status.SUCCESS)

    def _end(self, status: Status) -> Iterator[Behaviour]:
        self._last = 0
        halt_running(self.children)
        self.stop(status)
        yield self


class SequenceWithMemory(py_trees.composites.Composite):
    """BehaviorTree.CPP's ``SequenceWithMemory``: like ``Sequence``, but a child that FAILED
    is ticked again on the next tick instead of starting over from the first child. SUCCESS
    after the last child (the sequence then starts over)."""

    def __init__(self, name: str, children: Sequence[Behaviour]) -> None:
        super().__init__(name, list(children))
        self._index = 0

    def tick(self) -> Iterator[Behaviour]:
        if self.status == Status.INVALID or self.status == Status.SUCCESS:
            self._index = 0
            self.initialise()
        while self._index < len(self.children):
            child = self.children[self._index]
            self.current_child = child
            yield from child.tick()
            if child.status == Status.SUCCESS:
                self._index += 1
                continue
            if child.status == Status.FAILURE:
                self.stop(Status.FAILURE)
            else:
                self.status = Status.RUNNING
            yield self
            return
        self._index = 0
        self.stop(Status.SUCCESS)
        yield self

    def stop(self, new_status: Status = Status.INVALID) -> None:
        if new_status == Status.INVALID:
            self._index = 0
        super().stop(new_status)


class ParallelCount(py_trees.composites.Composite):
    """BehaviorTree.CPP's ``Parallel``: tick every child that has not finished yet; SUCCESS
    once ``success_count`` children succeeded, FAILURE once ``failure_count`` failed (a
    negative count means all children but ``-count - 1``: -1 = all); running children are
    then halted."""

    def __init__(
        self, name: str, children: Sequence[Behaviour], success_count: int, failure_count: int
    ) -> None:
        super().__init__(name, list(children))
        n = len(self.children)
        self.success_threshold = success_count if success_count >= 0 else n + success_count + 1
        self.failure_threshold = failure_count if failure_count >= 0 else n + failure_count + 1

    def tick(self) -> Iterator[Behaviour]:
        if self.status != Status.RUNNING:
            halt_running(self.children)
            self.initialise()
        for child in self.children:
            if child.status in (Status.SUCCESS, Status.FAILURE) and self.status == Status.RUNNING:
                continue
            yield from child.tick()
        ok = sum(c.status == Status.SUCCESS for c in self.children)
        bad = sum(c.status == Status.FAILURE for c in self.children)
        if ok >= self.success_threshold or bad >= self.failure_threshold:
            result = Status.SUCCESS if ok >= self.success_threshold else Status.FAILURE
            halt_running(self.children)
            self.stop(result)
        else:
            self.status = Status.RUNNING
        yield self


class IfThenElse(py_trees.composites.Composite):
    """BehaviorTree.CPP's ``IfThenElse``: tick the first child (the condition) until it
    finishes; on SUCCESS run the second, on FAILURE the third (FAILURE with two children).
    The branch's result is the node's."""

    def __init__(self, name: str, children: Sequence[Behaviour]) -> None:
        super().__init__(name, list(children))
        self._branch: Behaviour | None = None

    def tick(self) -> Iterator[Behaviour]:
        if self.status != Status.RUNNING:
            self._branch = None
            self.initialise()
        if self._branch is None:
            cond = self.children[0]
            yield from cond.tick()
            if cond.status == Status.RUNNING:
                self.status = Status.RUNNING
                yield self
                return
            if cond.status == Status.SUCCESS:
                self._branch = self.children[1]
            elif len(self.children) == 3:
                self._branch = self.children[2]
            else:
                self.stop(Status.FAILURE)
                yield self
                return
        branch = self._branch
        self.current_child = branch
        yield from branch.tick()
        if branch.status == Status.RUNNING:
            self.status = Status.RUNNING
        else:
            self._branch = None
            self.stop(branch.status)
        yield self


class WhileDoElse(py_trees.composites.Composite):
    """BehaviorTree.CPP's ``WhileDoElse``: every tick the condition (first child) is ticked;
    while it succeeds the second child runs (the third is halted), when it fails the third
    runs (FAILURE with two children) and the second is halted."""

    def tick(self) -> Iterator[Behaviour]:
        if self.status != Status.RUNNING:
            self.initialise()
        cond = self.children[0]
        yield from cond.tick()
        if cond.status == Status.RUNNING:
            self.status = Status.RUNNING
            yield self
            return
        take = 1 if cond.status == Status.SUCCESS else 2
        other = 2 if take == 1 else 1
        if other < len(self.children):
            halt_running([self.children[other]])
        if take >= len(self.children):
            self.stop(Status.FAILURE)
            yield self
            return
        branch = self.children[take]
        self.current_child = branch
        yield from branch.tick()
        if branch.status == Status.RUNNING:
            self.status = Status.RUNNING
        else:
            self.stop(branch.status)
        yield self


class _GatedDecorator(py_trees.decorators.Decorator):
    """A decorator that ticks its child only when :meth:`due` says so, or while the child
    runs; otherwise it reports RUNNING (as Nav2's rate and distance controllers do)."""

    def __init__(self, name: str, child: Behaviour) -> None:
        super().__init__(name=name, child=child)
        self._first = True

    def reset(self) -> None:
        """Called when the decorator starts afresh (after a halt)."""

    def due(self) -> bool:
        return False

    def ticked(self, status: Status) -> None:
        """Called after the child was ticked with its status."""

    def tick(self) -> Iterator[Behaviour]:
        if self.status == Status.INVALID:
            self._first = True
            self.reset()
            self.initialise()
        child = self.decorated
        if self._first or child.status == Status.RUNNING or self.due():
            self._first = False
            yield from child.tick()
            self.ticked(child.status)
            if child.status == Status.RUNNING:
                self.status = Status.RUNNING
            else:
                self.stop(child.status)
        else:
            self.status = Status.RUNNING
        yield self

    def update(self) -> Status:  # pragma: no cover - tick() decides
        return self.status


class RateController(_GatedDecorator):
    """Nav2's ``RateController``: tick the child at most ``hz`` times per second of the
    injected clock (and every tick while it runs); in between, RUNNING."""

    def __init__(self, name: str, child: Behaviour, hz: float, clock: Clock) -> None:
        super().__init__(name, child)
        if not (math.isfinite(hz) and hz > 0):
            raise ValueError(f"hz must be a positive number, got {hz}")
        self.period = 1.0 / hz
        self.clock = clock
        self._start = clock.now()

    def reset(self) -> None:
        self._start = self.clock.now()

    def due(self) -> bool:
        return self.clock.now() - self._start >= self.period - 1e-9

    def ticked(self, status: Status) -> None:
        if status == Status.SUCCESS:
            self._start = self.clock.now()


class DistanceController(_GatedDecorator):
    """Nav2's ``DistanceController``: tick the child again once the robot moved ``distance``
    meters (``position()``, ``map``) since the child last succeeded."""

    def __init__(
        self, name: str, child: Behaviour, distance: float, position: Callable[[], tuple[float, float] | None]
    ) -> None:
        super().__init__(name, child)
        self.distance = distance
        self.position = position
        self._from: tuple[float, float] | None = None

    def reset(self) -> None:
        self._from = self.position()

    def due(self) -> bool:
        here = self.position()
        if here is None or self._from is None:
            return False
        return math.dist(here, self._from) >= self.distance

    def ticked(self, status: Status) -> None:
        if status == Status.SUCCESS:
            self._from = self.position()


class SpeedController(RateController):
    """Nav2's ``SpeedController``: like :class:`RateController` with a rate that grows
    linearly with the robot's speed (``speed()``, m/s) from ``min_rate`` at ``min_speed`` to
    ``max_rate`` at ``max_speed``; a new goal (``goals()``) makes it tick at once."""

    def __init__(
        self,
        name: str,
        child: Behaviour,
        clock: Clock,
        rates: tuple[float, float],
        speeds: tuple[float, float],
        speed: Callable[[], float],
        goals: Callable[[], object],
    ) -> None:
        super().__init__(name, child, max(rates), clock)
        self.rates = rates
        self.speeds = speeds
        self.speed = speed
        self.goals = goals
        self._goals: object = None

    def due(self) -> bool:
        g = self.goals()
        if g != self._goals:
            self._goals = g
            return True
        (r0, r1), (s0, s1) = self.rates, self.speeds
        v = abs(self.speed())
        f = 0.0 if s1 <= s0 else min(1.0, max(0.0, (v - s0) / (s1 - s0)))
        rate = r0 + f * (r1 - r0)
        return rate > 0 and self.clock.now() - self._start >= 1.0 / rate - 1e-9


class GoalUpdatedController(_GatedDecorator):
    """Nav2's ``GoalUpdatedController``: tick the child the first time, while it runs, and
    when ``goals()`` (the blackboard ``goal`` / ``goals``) changed since the last tick."""

    def __init__(self, name: str, child: Behaviour, goals: Callable[[], object]) -> None:
        super().__init__(name, child)
        self.goals = goals
        self._seen: object = None

    def reset(self) -> None:
        self._seen = self.goals()

    def due(self) -> bool:
        g = self.goals()
        if g != self._seen:
            self._seen = g
            return True
        return False


class TimeoutDecorator(py_trees.decorators.Decorator):
    """BehaviorTree.CPP's ``Timeout``: FAILURE (the child is halted) when the child is still
    RUNNING ``seconds`` after it started (injected clock); otherwise the child's status."""

    def __init__(self, name: str, child: Behaviour, seconds: float, clock: Clock) -> None:
        super().__init__(name=name, child=child)
        self.seconds = seconds
        self.clock = clock
        self._t0 = 0.0

    def initialise(self) -> None:
        self._t0 = self.clock.now()

    def update(self) -> Status:
        if self.decorated.status == Status.RUNNING and self.clock.now() - self._t0 >= self.seconds - 1e-9:
            self.decorated.stop(Status.INVALID)
            self.feedback_message = f"timed out after {self.seconds:g} s"
            return Status.FAILURE
        return self.decorated.status


class DelayDecorator(py_trees.decorators.Decorator):
    """BehaviorTree.CPP's ``Delay``: RUNNING for ``seconds`` (injected clock) after it
    starts, then the child's status."""

    def __init__(self, name: str, child: Behaviour, seconds: float, clock: Clock) -> None:
        super().__init__(name=name, child=child)
        self.seconds = seconds
        self.clock = clock
        self._t0 = 0.0

    def initialise(self) -> None:
        self._t0 = self.clock.now()

    def tick(self) -> Iterator[Behaviour]:
        if self.status != Status.RUNNING:
            self.initialise()
        if self.clock.now() - self._t0 < self.seconds - 1e-9:
            self.status = Status.RUNNING
            yield self
            return
        yield from self.decorated.tick()
        status = self.decorated.status
        if status != Status.RUNNING:
            self.stop(status)
        else:
            self.status = status
        yield self

    def update(self) -> Status:  # pragma: no cover - tick() decides
        return self.decorated.status


class RunOnce(py_trees.decorators.Decorator):
    """BehaviorTree.CPP's ``RunOnce``: run the child to completion once; afterwards SUCCESS
    (``then_skip``, BT.CPP's SKIPPED) or the status of that one run, without ticking it."""

    def __init__(self, name: str, child: Behaviour, then_skip: bool = True) -> None:
        super().__init__(name=name, child=child)
        self.then_skip = then_skip
        self._result: Status | None = None

    def tick(self) -> Iterator[Behaviour]:
        if self._result is not None:
            self.status = Status.SUCCESS if self.then_skip else self._result
            yield self
            return
        yield from super().tick()

    def update(self) -> Status:
        status = self.decorated.status
        if status in (Status.SUCCESS, Status.FAILURE):
            self._result = status
        return status


class SingleTrigger(py_trees.decorators.Decorator):
    """Nav2's ``SingleTrigger``: tick the child until it finishes once (its status is the
    node's); afterwards FAILURE, until the node is halted and starts afresh."""

    def __init__(self, name: str, child: Behaviour) -> None:
        super().__init__(name=name, child=child)
        self._done = False

    def tick(self) -> Iterator[Behaviour]:
        if self.status == Status.INVALID:
            self._done = False
        if self._done:
            self.stop(Status.FAILURE)
            yield self
            return
        yield from super().tick()

    def update(self) -> Status:
        status = self.decorated.status
        if status != Status.RUNNING:
            self._done = True
        return status


class BeforeTick(py_trees.decorators.Decorator):
    """Run ``action()`` before every tick of the child; the child's status is the node's
    (Nav2's ``GoalUpdater`` copies its input goal to its output this way)."""

    def __init__(self, name: str, child: Behaviour, action: Callable[[], None]) -> None:
        super().__init__(name=name, child=child)
        self._action = action

    def tick(self) -> Iterator[Behaviour]:
        self._action()
        yield from super().tick()

    def update(self) -> Status:
        return self.decorated.status


def _length(path: tuple[object, ...]) -> float:
    pts = [(getattr(p, "x", 0.0), getattr(p, "y", 0.0)) for p in path]
    return sum(math.dist(a, b) for a, b in zip(pts, pts[1:], strict=False))


class PathLongerOnApproach(py_trees.decorators.Decorator):
    """Nav2's ``PathLongerOnApproach``: when a new ``path()`` to the same goal is more than
    ``length_factor`` times as long as the previous one and the previous one was shorter than
    ``prox_len`` m (the robot is close to the goal), tick the child (e.g. wait for the
    obstacle to clear); otherwise SUCCESS without ticking it."""

    def __init__(
        self, name: str, child: Behaviour, path: Callable[[], object], prox_len: float, length_factor: float
    ) -> None:
        super().__init__(name=name, child=child)
        self.path = path
        self.prox_len = prox_len
        self.length_factor = length_factor
        self._old: tuple[object, ...] = ()
        self._first = True

    def _longer(self, new: tuple[object, ...]) -> bool:
        old = self._old
        if not old or not new or new == old or new[-1] != old[-1]:
            return False
        return _length(old) < self.prox_len and _length(new) > self.length_factor * _length(old)

    def tick(self) -> Iterator[Behaviour]:
        value = self.path()
        new = tuple(value) if isinstance(value, (tuple, list)) else ()
        if self.decorated.status == Status.RUNNING or (not self._first and self._longer(new)):
            yield from self.decorated.tick()
            status = self.decorated.status
            if status != Status.RUNNING:
                self._old = new
                self.stop(status)
            else:
                self.status = status
            yield self
            return
        self._old, self._first = new, False
        self.stop(Status.SUCCESS)
        yield self

    def update(self) -> Status:  # pragma: no cover - tick() decides
        return self.status
