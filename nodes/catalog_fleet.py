"""This project's own nodes, for XML trees: the leaves, conditions and decorators the shipped
patrol and picking trees are built from (:mod:`nodes.leaves`, :mod:`nodes.conditions`,
:mod:`nodes.recovery`, :mod:`nodes.trees`), under the names the builders give them.

* ``FollowRoute`` (``tolerance``): one lap of the blackboard ``route`` (:class:`nodes.trees.FollowRoute`).
* ``Charge`` (``resume``, ``grace_s``): stand on the charger until the battery is at ``resume``
  (default: the robot's battery model).
* ``NextWaypoint`` (``waypoint`` out, ``tolerance``): the next pose of the blackboard
  ``route`` to visit (:class:`nodes.waypoints.NextWaypoint`), for trees acting at each waypoint.
* ``Idle``, ``CompletePick``.
* ``BatteryLow`` (``low``, ``resume``; default: the battery model, with the energy-based
  trigger of :func:`nodes.trees.charge_threshold` when no ``low`` is given): the latched
  low-battery condition. ``HasAssignment`` (``key``): the blackboard key holds something.
  ``NearPose`` (``pose``, ``tolerance``), ``IsLocalized``.
* ``RestartOnChange`` (``watch``: keys ``"task_id;route"``): restart the child when one of the
  keys changes while it runs.
* ``FollowWaypoints`` (``waypoints``): Nav2's waypoint follower as one goal.
"""

from __future__ import annotations

from py_trees.behaviour import Behaviour
from py_trees.blackboard import Blackboard

from fleet.types import Mode
from nodes.conditions import BatteryLow, HasAssignment, IsLocalized, NearPose
from nodes.leaves import Charge, CompletePick, Idle
from nodes.nav2_leaves import PortedAction, make_follow_waypoints
from nodes.ports import Literal, PortType, in_port, out_port
from nodes.recovery import RestartOnChange
from nodes.registry import Category, NodeArgs, NodeSpec, decorator, leaf
from nodes.trees import FollowRoute, charge_threshold
from nodes.waypoints import NextWaypoint

_F, _S = PortType.FLOAT, PortType.STRING


def _battery(a: NodeArgs, port: str, default: float) -> float:
    v = a.ports.get_float(port, default)
    if not 0.0 <= v <= 1.0:
        raise ValueError(f"{port} must be a battery fraction in [0, 1], got {v}")
    return v


def _watch(a: NodeArgs) -> Behaviour:
    keys = a.ports.get("watch")
    names = keys if isinstance(keys, tuple) else ()
    storage = Blackboard.storage
    resolved = [a.ctx.scope.resolve(k) for k in names]
    for k, r in zip(names, resolved, strict=True):
        if isinstance(r, Literal):
            raise ValueError(f"watch: key {k!r} is set to a literal in this subtree; watch a blackboard key")
    stored = [r for r in resolved if isinstance(r, str)]
    return RestartOnChange(a.name, a.children[0], lambda: tuple(storage.get(k) for k in stored))


def _mode(a: NodeArgs) -> Mode | None:
    v = a.ports.get("mode")
    return v if isinstance(v, Mode) else None


FLEET_SPECS: tuple[NodeSpec, ...] = (
    leaf(
        "FollowRoute",
        Category.ACTION,
        lambda a: FollowRoute(a.ctx.backend, name=a.name, tolerance_m=a.ports.get_float("tolerance", 0.3)),
        (in_port("tolerance", _F, "0.3"),),
        "one lap of the blackboard route",
    ),
    leaf(
        "Charge",
        Category.ACTION,
        lambda a: Charge(
            a.ctx.backend,
            a.ctx.clock,
            _battery(a, "resume", a.ctx.battery.resume),
            grace_s=a.ports.get_float("grace_s", 3.0),
            name=a.name,
        ),
        (in_port("resume", _F), in_port("grace_s", _F, "3.0")),
        "stand on the charger until the battery reaches resume",
    ),
    leaf(
        "NextWaypoint",
        Category.ACTION,
        lambda a: NextWaypoint(
            a.ctx.backend,
            lambda pose: a.ports.set("waypoint", pose),
            tolerance_m=a.ports.get_float("tolerance", 0.5),
            name=a.name,
        ),
        (out_port("waypoint", PortType.POSE, "{waypoint}"), in_port("tolerance", _F, "0.5")),
        "the next waypoint of the route (advances once the robot stands on the current one)",
    ),
    leaf(
        "Idle", Category.ACTION, lambda a: Idle(a.ctx.namespace, name=a.name), (), "always RUNNING, mode idle"
    ),
    leaf(
        "CompletePick",
        Category.ACTION,
        lambda a: CompletePick(a.ctx.namespace, name=a.name),
        (),
        "count the pick, clear it",
    ),
    leaf(
        "FollowWaypoints",
        Category.ACTION,
        lambda a: PortedAction(a.name, a.ctx.backend, a.ports, make_follow_waypoints, mode=_mode(a)),
        (
            in_port("waypoints", PortType.POSES),
            in_port("mode", PortType.MODE),
            out_port("error_code_id", PortType.INT),
        ),
        "visit waypoints (missed ones are skipped)",
    ),
    leaf(
        "BatteryLow",
        Category.CONDITION,
        lambda a: BatteryLow(
            a.ctx.backend,
            _battery(a, "low", a.ctx.battery.low),
            _battery(a, "resume", a.ctx.battery.resume),
            threshold=None
            if a.ports.get("low") is not None
            else charge_threshold(a.ctx.namespace, a.ctx.backend, a.ctx.battery),
            name=a.name,
        ),
        (in_port("low", _F), in_port("resume", _F)),
        "battery below the energy to reach the charger (or a fixed low), latched until resume",
    ),
    leaf(
        "HasAssignment",
        Category.CONDITION,
        lambda a: HasAssignment(a.ctx.namespace, a.ports.get_str("key"), name=a.name),
        (in_port("key", _S, required=True),),
        "the robot's blackboard key holds an assignment",
    ),
    leaf(
        "NearPose",
        Category.CONDITION,
        lambda a: NearPose(
            a.ctx.backend, lambda: a.ports.get_pose("pose"), a.ports.get_float("tolerance", 0.3), name=a.name
        ),
        (in_port("pose", PortType.POSE, required=True), in_port("tolerance", _F, "0.3")),
        "the robot within tolerance of pose",
    ),
    leaf(
        "IsLocalized",
        Category.CONDITION,
        lambda a: IsLocalized(a.ctx.backend, name=a.name),
        (),
        "the robot's pose is known",
    ),
    decorator(
        "RestartOnChange",
        _watch,
        (in_port("watch", PortType.KEYS, required=True),),
        "restart the child when a watched key changes",
    ),
)
