"""Behavior-tree nodes of the fleet: action leaves, conditions, Nav2-style recovery
composites, per-robot blackboards and the functions that build each robot's tree.

Leaves talk only to a :class:`fleet.navigation.NavigationBackend`; nothing here reads the
wall clock or imports ROS. See ``docs/behavior_trees.md``.
"""

from nodes.blackboard import DEFAULTS, read_key, robot_blackboard
from nodes.conditions import BatteryLow, HasAssignment, IsLocalized, IsStuck, NearPose
from nodes.leaves import (
    BackUpAction,
    Charge,
    CompletePick,
    DriveOnHeadingAction,
    FollowWaypointsAction,
    GoalAction,
    Idle,
    NavigateThroughPosesAction,
    NavigateToPoseAction,
    SpinAction,
    WaitAction,
)
from nodes.recovery import RecoveryNode, RestartOnChange, RoundRobin, recovery_actions
from nodes.trees import FollowRoute, build_tree, dump_tree, patrol_tree, picking_tree

__all__ = [
    "DEFAULTS",
    "BackUpAction",
    "BatteryLow",
    "Charge",
    "CompletePick",
    "DriveOnHeadingAction",
    "FollowRoute",
    "FollowWaypointsAction",
    "GoalAction",
    "HasAssignment",
    "Idle",
    "IsLocalized",
    "IsStuck",
    "NavigateThroughPosesAction",
    "NavigateToPoseAction",
    "NearPose",
    "RecoveryNode",
    "RestartOnChange",
    "RoundRobin",
    "SpinAction",
    "WaitAction",
    "build_tree",
    "dump_tree",
    "patrol_tree",
    "picking_tree",
    "read_key",
    "recovery_actions",
    "robot_blackboard",
]
