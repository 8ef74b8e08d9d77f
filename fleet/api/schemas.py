"""The JSON shapes of the HTTP API's answers, as pydantic models so that ``/openapi.json``
documents them (the app builds the JSON itself; these models are its contract). Units: m,
rad, s; poses in the ``map`` frame; times ISO 8601 (UTC) unless named ``t`` (fleet clock)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, Field

TaskStateName = Literal["queued", "assigned", "active", "completed", "failed", "canceled"]


class ErrorOut(BaseModel):
    """Every 4xx answer: what went wrong, the field it is about (``""``: the whole request)."""

    error: str = Field(description="the reason, for people")
    field: str = Field(description="the offending field, e.g. waypoints[2].action")
    status: int


class TaskEventOut(BaseModel):
    seq: int = Field(description="orders every event of the service")
    task_id: str
    event: str = Field(
        description="queued, assigned, active, progress, requeued, completed, failed, canceled, restored"
    )
    state: TaskStateName
    robot: str | None
    assignment: str | None
    text: str
    at: str | None
    t: float = Field(description="fleet clock (s)")


class TaskOut(BaseModel):
    """A task (``POST /api/tasks`` answers with it, state ``queued``)."""

    id: str = Field(description="never reused, also across restarts")
    kind: Literal["patrol", "pick", "go_to", "inspection", "charge", "park"]
    state: TaskStateName
    robot: str | None = Field(description="the robot holding the task, or the last one that did")
    name: str
    source: Literal["config", "submitted"]
    priority: int
    only_robot: str | None = Field(description="the one robot allowed to take it (submitted as robot)")
    assignment: str | None = Field(description="the current hand-over's id (the robot's task_id)")
    attempts: int
    laps: int
    steps_done: int
    steps_total: int
    message: str
    submitted_by: str
    created_at: str | None
    assigned_at: str | None
    started_at: str | None
    ended_at: str | None
    updated_at: str | None
    cancel_requested: bool
    spec: dict[str, Any] = Field(description="the task as submitted")
    events: list[TaskEventOut] | None = Field(None, description="the latest events (GET /api/tasks/{id})")


class PoseOut(BaseModel):
    x: float
    y: float
    theta: float


class RobotOut(BaseModel):
    """A robot's latest state."""

    name: str
    state: str = Field(
        description="its mode (idle, patrol, picking, task, charging, recovery, paused, estop) or dead"
    )
    mode: str
    health: Literal["alive", "silent", "stuck", "dead"]
    battery: float = Field(description="fraction in [0, 1]")
    charging: bool
    pose: PoseOut | None
    heading: float | None = Field(description="rad, map frame")
    task: str | None = Field(description="the task id it works on")
    assignment: str | None
    leaf: str
    laps: int
    distance_m: float
    stuck: bool
    t: float = Field(description="fleet time of its status (s)")


class ControlOut(BaseModel):
    """The fleet's control state and its last change."""

    state: Literal["running", "paused", "estop"]
    estop: bool
    paused: bool
    seq: int
    t: float
    wall: float
    at: str | None
    by: str
    action: str
    reason: str


class FleetOut(BaseModel):
    name: str
    control: ControlOut
    history: list[ControlOut]
    robots: int
    tasks: dict[str, int] = Field(description="tasks per state")
    traffic: bool
    t: float


class CommandIn(BaseModel):
    """Optional body of the fleet commands."""

    by: str | None = Field(None, max_length=256, description="who (default: X-Fleet-User or the client)")
    reason: str | None = Field(None, max_length=256)


class MapOut(BaseModel):
    name: str
    image: str
    source: str
    resolution: float
    origin: list[float]
    width: int
    height: int
    extent: list[float] = Field(description="[xmin, xmax, ymin, ymax]")


class NodeOut(BaseModel):
    name: str
    x: float
    y: float


class NamedPoseOut(BaseModel):
    name: str
    x: float
    y: float
    theta: float
    node: str | None = None


class RoadmapOut(BaseModel):
    """The roadmap and the site's docks (``map`` frame, m, rad)."""

    nodes: list[NodeOut]
    edges: list[list[str]] = Field(description="[a, b] node names; edges are two-way")
    chargers: list[NamedPoseOut]
    stations: list[NamedPoseOut]
    parking: list[NamedPoseOut]


class SegmentOut(BaseModel):
    robot: str
    a: list[float] = Field(description="[x, y] of one end")
    b: list[float]


class TrafficOut(BaseModel):
    """Reserved roadmap segments and nodes (traffic management on), by robot."""

    enabled: bool
    segments: list[SegmentOut]
    nodes: list[dict[str, Any]] = Field(description="[{robot, name, x, y}] nodes held")
