"""Every node a tree loaded from XML may use, by its BehaviorTree.CPP / Nav2 name
(:func:`default_registry`); ``docs/behavior_trees.md`` lists them with their ports.

* BehaviorTree.CPP's own: ``Sequence``, ``SequenceWithMemory`` (v3: ``SequenceStar``),
  ``Fallback``, ``ReactiveSequence``, ``ReactiveFallback``, ``Parallel``, ``IfThenElse``,
  ``WhileDoElse``; ``Inverter``, ``ForceSuccess``, ``ForceFailure``,
  ``KeepRunningUntilFailure``, ``Repeat``, ``RetryUntilSuccessful``, ``Timeout``, ``Delay``,
  ``RunOnce``; ``AlwaysSuccess``, ``AlwaysFailure``, ``SetBlackboard``, ``Sleep``.
* Nav2's control nodes and decorators (:mod:`nodes.control`, :mod:`nodes.recovery`), action
  nodes (:mod:`nodes.nav2_leaves`) and conditions (:mod:`nodes.nav2_conditions`).
* This project's (:mod:`nodes.catalog_fleet`): ``FollowRoute``, ``Charge``, ``Idle``,
  ``CompletePick``, ``BatteryLow``, ``HasAssignment``, ``NearPose``, ``IsLocalized``,
  ``RestartOnChange``, ``FollowWaypoints``.

BehaviorTree.CPP's ``Sequence`` remembers its running child and starts over after a failure
(py_trees ``Sequence(memory=True)``), ``ReactiveSequence`` re-checks every child each tick
(``memory=False``); ``Fallback`` / ``ReactiveFallback`` likewise. ``Repeat`` runs one cycle
per tick (py_trees' ``Repeat``).
"""

from __future__ import annotations

import py_trees
from py_trees.behaviour import Behaviour
from py_trees.common import Status

from nodes.catalog_fleet import FLEET_SPECS
from nodes.catalog_nav2 import NAV2_SPECS
from nodes.control import (
    DelayDecorator,
    IfThenElse,
    ParallelCount,
    RunOnce,
    SequenceWithMemory,
    TimeoutDecorator,
    WhileDoElse,
)
from nodes.nav2_leaves import PortedLeaf
from nodes.ports import Ports, PortType, in_port, out_port
from nodes.registry import Category, NodeArgs, NodeRegistry, NodeSpec, control, decorator, leaf

_F, _I, _B, _S, _A = PortType.FLOAT, PortType.INT, PortType.BOOL, PortType.STRING, PortType.ANY


def _one(a: NodeArgs) -> Behaviour:
    return a.children[0]


def _status(status: Status) -> NodeSpec:
    name = "AlwaysSuccess" if status == Status.SUCCESS else "AlwaysFailure"
    return leaf(
        name,
        Category.ACTION,
        lambda a: PortedLeaf(a.name, a.ports, lambda _p: status),
        doc=f"{status.name} at once",
    )


def _set_blackboard(a: NodeArgs) -> Behaviour:
    def step(p: Ports) -> Status:
        p.set("output_key", p.get("value"))
        return Status.SUCCESS

    return PortedLeaf(a.name, a.ports, step)


def _sleep(a: NodeArgs) -> Behaviour:
    return DelayDecorator(
        a.name,
        PortedLeaf(f"{a.name}.done", a.ports, lambda _p: Status.SUCCESS),
        a.ports.get_float("msec") / 1000.0,
        a.ctx.clock,
    )


def _ms(a: NodeArgs, port: str) -> float:
    v = a.ports.get_float(port, -1.0)
    if v < 0:
        raise ValueError(f"{port} must be a number of milliseconds >= 0")
    return v / 1000.0


BT_SPECS: tuple[NodeSpec, ...] = (
    control(
        "Sequence",
        lambda a: py_trees.composites.Sequence(a.name, memory=True, children=a.children),
        doc="children in order; resumes the running child; starts over after a failure",
    ),
    control(
        "SequenceWithMemory",
        lambda a: SequenceWithMemory(a.name, a.children),
        doc="like Sequence, but a failed child is retried, not the whole sequence",
    ),
    control(
        "Fallback",
        lambda a: py_trees.composites.Selector(a.name, memory=True, children=a.children),
        doc="children in order until one does not fail; resumes the running child",
    ),
    control(
        "ReactiveSequence",
        lambda a: py_trees.composites.Sequence(a.name, memory=False, children=a.children),
        doc="every child re-checked each tick",
    ),
    control(
        "ReactiveFallback",
        lambda a: py_trees.composites.Selector(a.name, memory=False, children=a.children),
        doc="every higher-priority child re-checked each tick",
    ),
    control(
        "Parallel",
        lambda a: ParallelCount(
            a.name, a.children, a.ports.get_int("success_count", -1), a.ports.get_int("failure_count", 1)
        ),
        (in_port("success_count", _I, "-1"), in_port("failure_count", _I, "1")),
        "all children each tick; thresholds of successes / failures",
    ),
    control(
        "IfThenElse", lambda a: IfThenElse(a.name, a.children), doc="condition, then, else", children=(2, 3)
    ),
    control(
        "WhileDoElse",
        lambda a: WhileDoElse(a.name, a.children),
        doc="reactive condition, do, else",
        children=(2, 3),
    ),
    decorator("Inverter", lambda a: py_trees.decorators.Inverter(a.name, _one(a)), doc="SUCCESS <-> FAILURE"),
    decorator(
        "ForceSuccess",
        lambda a: py_trees.decorators.FailureIsSuccess(a.name, _one(a)),
        doc="FAILURE -> SUCCESS",
    ),
    decorator(
        "ForceFailure",
        lambda a: py_trees.decorators.SuccessIsFailure(a.name, _one(a)),
        doc="SUCCESS -> FAILURE",
    ),
    decorator(
        "KeepRunningUntilFailure",
        lambda a: py_trees.decorators.SuccessIsRunning(a.name, _one(a)),
        doc="SUCCESS -> RUNNING (the child starts again)",
    ),
    decorator(
        "Repeat",
        lambda a: py_trees.decorators.Repeat(a.name, _one(a), a.ports.get_int("num_cycles", 1)),
        (in_port("num_cycles", _I, required=True),),
        "run the child num_cycles times (-1: forever), one cycle per tick",
    ),
    decorator(
        "RetryUntilSuccessful",
        lambda a: py_trees.decorators.Retry(a.name, _one(a), a.ports.get_int("num_attempts", 1)),
        (in_port("num_attempts", _I, required=True),),
        "retry a failing child up to num_attempts times",
    ),
    decorator(
        "Timeout",
        lambda a: TimeoutDecorator(a.name, _one(a), _ms(a, "msec"), a.ctx.clock),
        (in_port("msec", _F, required=True),),
        "FAILURE when the child runs longer than msec (simulated time)",
    ),
    decorator(
        "Delay",
        lambda a: DelayDecorator(a.name, _one(a), _ms(a, "delay_msec"), a.ctx.clock),
        (in_port("delay_msec", _F, required=True),),
        "wait delay_msec, then tick the child",
    ),
    decorator(
        "RunOnce",
        lambda a: RunOnce(a.name, _one(a), a.ports.get_bool("then_skip", True)),
        (in_port("then_skip", _B, "true"),),
        "run the child once; then SUCCESS (then_skip) or its result",
    ),
    _status(Status.SUCCESS),
    _status(Status.FAILURE),
    leaf(
        "SetBlackboard",
        Category.ACTION,
        _set_blackboard,
        (in_port("value", _A, required=True), out_port("output_key", _A)),
        "write value to a key",
    ),
    leaf(
        "Sleep",
        Category.ACTION,
        _sleep,
        (in_port("msec", _F, required=True),),
        "RUNNING for msec (simulated time)",
    ),
)


def default_registry() -> NodeRegistry:
    """Every node this project ships (see the module docstring); a fresh registry each call."""
    reg = NodeRegistry((*BT_SPECS, *NAV2_SPECS, *FLEET_SPECS))
    reg.alias("SequenceStar", "SequenceWithMemory")
    return reg
