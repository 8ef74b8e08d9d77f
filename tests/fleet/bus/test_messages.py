"""The wire messages of :mod:`fleet.messages`: today's bytes, strict decoding whose errors name
the field and the reason, and the send-side checks."""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from typing import Any

import msgspec
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fleet.messages import (
    MAX_BRIDGE_PAYLOAD,
    MAX_PAYLOAD_BYTES,
    CancelRequest,
    ClockMsg,
    GoalRequest,
    Grant,
    NavState,
    PickOrder,
    StatusRecord,
    TaskMessage,
    goal_from_dict,
    goal_to_dict,
)
from fleet.messages.nav import (
    CANCEL_REQUEST_CODEC,
    CLOCK_CODEC,
    GOAL_REQUEST_CODEC,
    NAV_STATE_CODEC,
    goal_message,
    goal_of,
)
from fleet.types import (
    BackUp,
    DriveOnHeading,
    Feedback,
    FollowWaypoints,
    GoalState,
    GoalStatus,
    NavigateThroughPoses,
    NavigateToPose,
    Pose2D,
    RobotState,
    Spin,
    Wait,
)

# ----------------------------------------------------------------------------- today's bytes
# Written by the codec before msgspec (json.dumps with compact separators), kept verbatim:
# a process on either side of the change reads the other's messages.

OLD_STATUS = (
    b'{"robot":"robot1","ns":"/robot1","t":123.45,"pose":[12.3,4.5,1.571],"battery":0.83,'
    b'"charging":false,"stuck":false,"bt":"RUNNING","leaf":"FollowRoute","mode":"patrol",'
    b'"task_id":"p-0003","laps":2,"progress":0.4,"distance_m":123.4,"collisions":0,"seq":17,'
    b'"picks_done":1,"v":1}'
)
STATUS = StatusRecord(
    robot="robot1", ns="/robot1", t=123.45, pose=(12.3, 4.5, 1.571), battery=0.83, charging=False,
    stuck=False, bt="RUNNING", leaf="FollowRoute", mode="patrol", task_id="p-0003", laps=2,
    progress=0.4, distance_m=123.4, collisions=0, seq=17, picks_done=1,
)  # fmt: skip

OLD_PATROL = (
    b'{"v":1,"task_id":"p-0003","kind":"patrol","robot":"robot1","route":"aisle_loop_1",'
    b'"poses":[[3.0,3.0,0.0],[20.0,3.0,1.571]],"charger":[1.0,1.0,0.0]}'
)
PATROL = TaskMessage(
    "p-0003", "patrol", "robot1", "aisle_loop_1", (Pose2D(3, 3, 0), Pose2D(20, 3, 1.571)), Pose2D(1, 1, 0)
)
OLD_PICK = (
    b'{"v":1,"task_id":"k-0002","kind":"pick","robot":"robot2","pick":{"name":"order7",'
    b'"shelf":[8.0,12.0,1.571],"drop":[2.0,18.0,3.142],"dwell_s":5.0}}'
)
PICK = TaskMessage(
    "k-0002", "pick", "robot2", pick=PickOrder("order7", Pose2D(8, 12, 1.571), Pose2D(2, 18, 3.142), 5.0)
)
OLD_IDLE = b'{"v":1,"task_id":null,"kind":"idle"}'
IDLE = TaskMessage(None, "idle")

OLD_GRANT = (
    b'{"v":1,"robot":"robot1","path_id":3,"horizon":7,"current":"a","nodes":["b","c"],'
    b'"poses":[[1.0,2.0,0.0],[3.0,2.0,0.5]],"final":false,"waiting":false,"done":false,'
    b'"alive":true,"task_id":"p-0001","purpose":"patrol","laps":2,"seq":11}'
)
GRANT = Grant(
    "robot1", 3, 7, "a", ("b", "c"), (Pose2D(1.0, 2.0, 0.0), Pose2D(3.0, 2.0, 0.5)),
    task_id="p-0001", purpose="patrol", laps=2, seq=11,
)  # fmt: skip

OLD_GOAL_REQUEST = (
    b'{"v":1,"goal_id":"/robot1@3fa29c01#7","client":"3fa29c01","seq":7,"goal":'
    b'{"kind":"navigate_to_pose","pose":[8.5,4.0,1.571],"behavior_tree":""}}'
)
GOAL_REQUEST = GoalRequest(
    "/robot1@3fa29c01#7", "3fa29c01", 7, goal_message(NavigateToPose(Pose2D(8.5, 4.0, 1.571)))
)
OLD_GOALS = [
    (b'{"kind":"navigate_through_poses","poses":[[1.0,2.0,3.0]],"behavior_tree":""}',
     NavigateThroughPoses((Pose2D(1, 2, 3),))),
    (b'{"kind":"follow_waypoints","poses":[[1.0,2.0,3.0]]}', FollowWaypoints((Pose2D(1, 2, 3),))),
    (b'{"kind":"spin","target_yaw":1.5,"time_allowance_s":10.0}', Spin(1.5, time_allowance_s=10.0)),
    (b'{"kind":"backup","distance_m":0.5,"speed_mps":0.1,"time_allowance_s":10.0}', BackUp(0.5)),
    (b'{"kind":"drive_on_heading","distance_m":1.0,"speed_mps":0.2,"time_allowance_s":10.0}',
     DriveOnHeading(1.0, speed_mps=0.2)),
    (b'{"kind":"wait","duration_s":2.0}', Wait(2.0)),
]  # fmt: skip
OLD_STATE = (
    b'{"v":1,"robot":"robot1","t":42.3,"robot_state":{"pose":[5.1,4.0,0.02],"linear_velocity":0.8,'
    b'"angular_velocity":0.0,"battery":0.97,"charging":false,"stuck":false,"distance_m":3.2,'
    b'"collisions":0},"goals":{"/robot1@3fa29c01#7":{"kind":"navigate_to_pose","status":"executing",'
    b'"feedback":{"current_pose":[5.1,4.0,0.02],"navigation_time_s":3.9,"estimated_time_remaining_s":4.3,'
    b'"distance_remaining_m":3.6,"number_of_recoveries":0},"error_code":0,"error_msg":""},'
    b'"/robot1@3fa29c01#6":{"kind":"follow_waypoints","status":"aborted","feedback":{"current_waypoint":2},'
    b'"error_code":601,"error_msg":"boom","missed_waypoints":[1]}}}'
)
EXECUTING = GoalState(
    "/robot1@3fa29c01#7", "navigate_to_pose", GoalStatus.EXECUTING,
    Feedback(current_pose=Pose2D(5.1, 4.0, 0.02), navigation_time_s=3.9, estimated_time_remaining_s=4.3,
             distance_remaining_m=3.6, number_of_recoveries=0),
)  # fmt: skip
ABORTED = GoalState(
    "/robot1@3fa29c01#6", "follow_waypoints", GoalStatus.ABORTED, Feedback(current_waypoint=2),
    error_code=601, error_msg="boom", missed_waypoints=(1,),
)  # fmt: skip
ROBOT_STATE = RobotState(Pose2D(5.1, 4.0, 0.02), 0.8, 0.0, 0.97, False, False, 3.2, 0)
OLD_CLOCK = b'{"v":1,"t":42.3,"step":846,"step_s":0.05,"speed":5.0}'
OLD_CANCEL = b'{"v":1,"goal_id":"/robot1@3fa29c01#7"}'


def test_todays_status_bytes_decode_and_encode_to_the_same_object() -> None:
    assert StatusRecord.from_json(OLD_STATUS) == STATUS
    assert json.loads(STATUS.to_json()) == json.loads(OLD_STATUS)
    # the one difference: "v" now comes first, as docs/status_bus.md shows it
    assert STATUS.to_json() == b'{"v":1,' + OLD_STATUS[1 : -len(b',"v":1}')] + b"}"
    assert StatusRecord.from_dict(STATUS.to_dict()) == STATUS


@pytest.mark.parametrize(
    ("old", "msg"), [(OLD_PATROL, PATROL), (OLD_PICK, PICK), (OLD_IDLE, IDLE)], ids=["patrol", "pick", "idle"]
)
def test_todays_task_bytes_round_trip_byte_for_byte(old: bytes, msg: TaskMessage) -> None:
    assert TaskMessage.from_json(old) == msg
    assert msg.to_json() == old
    assert TaskMessage.from_dict(json.loads(old)) == msg


def test_todays_grant_bytes_round_trip_byte_for_byte() -> None:
    assert Grant.from_json(OLD_GRANT) == GRANT
    # the one addition: the coordinator's epoch (docs/protocol.md), last
    assert GRANT.to_json() == OLD_GRANT[:-1] + b',"epoch":0}'
    assert Grant.from_dict(GRANT.to_dict()) == GRANT
    assert msgspec.structs.replace(GRANT, seq=12).seq == 12


def test_todays_navigation_bytes_round_trip_byte_for_byte() -> None:
    assert GOAL_REQUEST.to_json() == OLD_GOAL_REQUEST
    assert GOAL_REQUEST_CODEC.decode(OLD_GOAL_REQUEST) == GOAL_REQUEST
    for old, goal in OLD_GOALS:
        assert json.dumps(goal_to_dict(goal), separators=(",", ":")).encode() == old
        assert goal_from_dict(json.loads(old)) == goal
        assert goal_of(goal_message(goal)) == goal
    state = NavState.build(
        "robot1", 42.3, ROBOT_STATE, {EXECUTING.goal_id: EXECUTING, ABORTED.goal_id: ABORTED}
    )
    # the one addition: the simulator's session id (docs/protocol.md), last; old bytes still decode
    assert state.to_json() == OLD_STATE[:-1] + b',"src":""}'
    back = NAV_STATE_CODEC.decode(OLD_STATE)
    assert back.goal_state(EXECUTING.goal_id) == EXECUTING
    assert back.goal_state(ABORTED.goal_id) == ABORTED
    assert ClockMsg(42.3, 846, 0.05, 5.0).to_json() == OLD_CLOCK[:-1] + b',"src":""}'
    assert CLOCK_CODEC.decode(OLD_CLOCK) == ClockMsg(42.3, 846, 0.05, 5.0)
    assert CLOCK_CODEC.decode(b'{"v":1,"t":2.5}') == ClockMsg(2.5)
    assert CancelRequest("/robot1@3fa29c01#7").to_json() == OLD_CANCEL
    assert CANCEL_REQUEST_CODEC.decode(OLD_CANCEL).goal_id == "/robot1@3fa29c01#7"


# ----------------------------------------------------------------------------- receive errors


def _status(**changes: Any) -> bytes:
    d = {**json.loads(OLD_STATUS), **changes}
    return json.dumps({k: v for k, v in d.items() if v is not _DROP}).encode()


_DROP = object()
_HUGE = _status(pad="a" * MAX_PAYLOAD_BYTES)
_HUGE_REQUEST = b'{"v":1,"pad":"' + b"a" * MAX_BRIDGE_PAYLOAD + b'"}'

STATUS_ERRORS = [
    ("wrong type", _status(battery="x"), "status.battery: expected a finite number, got 'x'"),
    ("null number", _status(t=None), "status.t: expected a finite number, got None"),
    ("int for bool", _status(charging=1), "status.charging: expected true or false, got 1"),
    ("bool for int", _status(laps=True), "status.laps: expected an integer, got True"),
    ("float for int", _status(laps=1.5), "status.laps: expected an integer, got 1.5"),
    ("negative count", _status(collisions=-1), "status.collisions: must be >= 0, got -1"),
    ("short pose", _status(pose=[1, 2]), "status.pose: expected [x, y, theta] of 3 finite numbers, got [1, 2]"),
    ("pose element", _status(pose=[1, 2, "a"]), "status.pose[2]: expected a finite number, got 'a'"),
    ("infinity", OLD_STATUS.replace(b'"t":123.45', b'"t":1e999'), "status.t: expected a finite number, got inf"),
    ("NaN", OLD_STATUS.replace(b'"t":123.45', b'"t":NaN'), "payload: not JSON (JSON is malformed"),
    ("version 2", _status(v=2), "status.v: unsupported version 2 (expected 1)"),
    ("version text", _status(v="1"), "status.v: unsupported version '1' (expected 1)"),
    ("version 0", _status(v=0), "status.v: unsupported version 0 (expected 1)"),
    ("no version", _status(v=_DROP), "status.v: missing"),
    ("missing field", _status(seq=_DROP), "status.seq: missing"),
    ("robot name", _status(robot="a/b"), "status.robot: not a valid robot name (use letters, digits, _ . -), got 'a/b'"),
    ("long string", _status(leaf="x" * 300), "status.leaf: string longer than 256 characters"),
    ("huge payload", _HUGE, f"payload: {len(_HUGE)} bytes is larger than {MAX_PAYLOAD_BYTES}"),
    ("garbage bytes", b"\xff\xfe\x00garbage", "payload: not UTF-8 (invalid start byte at byte 0)"),
    ("bad UTF-8 in a string", OLD_STATUS.replace(b"FollowRoute", b"Follow\xc3("), "payload: not UTF-8"),
    ("not JSON", b"not json at all", "payload: not JSON (JSON is malformed"),
    ("trailing bytes", OLD_STATUS + b"}", "payload: not JSON (JSON is malformed: trailing characters"),
    ("truncated", OLD_STATUS[:50], "payload: not JSON (Input data was truncated)"),
    ("empty", b"", "payload: not JSON (Input data was truncated)"),
    ("not an object", b"[1, 2, 3]", "status: expected a JSON object, got [1, 2, 3]"),
    ("deep nesting", b"[" * 100000, "status: expected a JSON object"),
    ("deep object", b"{" * 100000, "payload: not JSON"),
]  # fmt: skip


@pytest.mark.parametrize(
    ("payload", "error"), [c[1:] for c in STATUS_ERRORS], ids=[c[0] for c in STATUS_ERRORS]
)
def test_malformed_status_errors_name_the_field_and_the_reason(payload: bytes, error: str) -> None:
    with pytest.raises(ValueError) as err:
        StatusRecord.from_json(payload)
    assert str(err.value).startswith(error), str(err.value)


def test_status_from_dict_rejects_non_finite_numbers_and_defaults_picks_done() -> None:
    d = STATUS.to_dict()
    with pytest.raises(ValueError, match=r"^status\.battery: expected a finite number, got nan$"):
        StatusRecord.from_dict({**d, "battery": math.nan})
    with pytest.raises(ValueError, match=r"^status\.pose\[1\]: expected a finite number, got inf$"):
        StatusRecord.from_dict({**d, "pose": [0.0, math.inf, 0.0]})
    with pytest.raises(ValueError, match=r"^status: expected a JSON object, got 'x'$"):
        StatusRecord.from_dict("x")
    del d["picks_done"]
    assert StatusRecord.from_dict(d).picks_done == 0


TASK_ERRORS = [
    ("unknown kind", b'{"v":1,"task_id":"x","kind":"dance"}', "task.kind: 'dance' is not one of patrol, pick, go_to, inspection, charge, park, idle"),
    ("patrol without poses", b'{"v":1,"task_id":"p","kind":"patrol"}', "task.poses: a patrol task needs at least one pose"),
    ("patrol without id", b'{"v":1,"task_id":null,"kind":"patrol","poses":[[1,2,3]]}', "task.task_id: a patrol task needs an id"),
    ("pick without pick", b'{"v":1,"task_id":"k","kind":"pick"}', "task.pick: missing (a pick task needs shelf, drop and dwell_s)"),
    ("pick without drop", b'{"v":1,"task_id":"k","kind":"pick","pick":{"shelf":[1,2,3],"dwell_s":1}}', "task.pick.drop: missing"),
    ("bad pose", b'{"v":1,"task_id":"p","kind":"patrol","poses":[[1,2]]}', "task.poses[0]: expected [x, y, theta] of 3 finite numbers"),
    ("bad charger", b'{"v":1,"task_id":null,"kind":"idle","charger":"home"}', "task.charger: expected [x, y, theta] of 3 finite numbers or null, got 'home'"),
    ("bad robot", b'{"v":1,"task_id":null,"kind":"idle","robot":"a b"}', "task.robot: not a valid robot name"),
    ("missing id", b'{"v":1,"kind":"idle"}', "task.task_id: missing"),
    ("version", b'{"v":2,"task_id":null,"kind":"idle"}', "task.v: unsupported version 2 (expected 1)"),
    ("too many poses", json.dumps({"v": 1, "task_id": "p", "kind": "patrol", "poses": [[0, 0, 0]] * 10001}).encode(),
     "task.poses: more than 10000 items"),
]  # fmt: skip


@pytest.mark.parametrize(("payload", "error"), [c[1:] for c in TASK_ERRORS], ids=[c[0] for c in TASK_ERRORS])
def test_malformed_task_errors_name_the_field_and_the_reason(payload: bytes, error: str) -> None:
    with pytest.raises(ValueError) as err:
        TaskMessage.from_json(payload)
    assert str(err.value).startswith(error), str(err.value)


def test_malformed_grants_are_rejected() -> None:
    d = GRANT.to_dict()
    cases = [
        ({**d, "nodes": ["b"]}, "grant.poses: 1 nodes but 2 poses"),
        ({**d, "path_id": "3"}, "grant.path_id: expected an integer, got '3'"),
        (
            {**d, "poses": [[1, 2, math.nan], [3, 2, 0]]},
            "grant.poses[0][2]: expected a finite number, got nan",
        ),
        ({**d, "seq": -1}, "grant.seq: must be >= 0, got -1"),
        ({k: v for k, v in d.items() if k != "robot"}, "grant.robot: missing"),
    ]
    for bad, error in cases:
        with pytest.raises(ValueError) as err:
            Grant.from_dict(bad)
        assert str(err.value) == error
    with pytest.raises(ValueError, match=r"^grant\.final: expected true or false, got 1$"):
        Grant.from_json(json.dumps({**d, "final": 1}))


def _request(**goal: Any) -> bytes:
    return json.dumps({"v": 1, "goal_id": "g", "client": "c", "seq": 1, "goal": goal}).encode()


NAV_ERRORS = [
    (GOAL_REQUEST_CODEC, _request(kind="dance"), "goal_request.goal.kind: unknown value 'dance' (expected one of navigate_to_pose, "),
    (GOAL_REQUEST_CODEC, _request(pose=[1, 2, 3]), "goal_request.goal.kind: missing"),
    (GOAL_REQUEST_CODEC, _request(kind="navigate_to_pose", pose=[1, 2]), "goal_request.goal.pose: expected [x, y, theta] of 3 finite numbers"),
    (GOAL_REQUEST_CODEC, _request(kind="spin", target_yaw=1.0), "goal_request.goal.time_allowance_s: missing"),
    (GOAL_REQUEST_CODEC, _request(kind="wait", duration_s="long"), "goal_request.goal.duration_s: expected a finite number, got 'long'"),
    (GOAL_REQUEST_CODEC, b'{"v":1,"goal_id":"g","client":"c","seq":-1,"goal":{"kind":"wait","duration_s":1}}', "goal_request.seq: must be >= 0, got -1"),
    (GOAL_REQUEST_CODEC, b"{}", "goal_request.v: missing"),
    (GOAL_REQUEST_CODEC, _HUGE_REQUEST, f"payload: {len(_HUGE_REQUEST)} bytes is larger than {MAX_BRIDGE_PAYLOAD}"),
    (CANCEL_REQUEST_CODEC, b'{"v":1}', "cancel_request.goal_id: missing"),
    (CANCEL_REQUEST_CODEC, b'{"v":1,"goal_id":7}', "cancel_request.goal_id: expected a string, got 7"),
    (CLOCK_CODEC, b'{"v":1,"speed":1}', "clock.t: missing"),
    (CLOCK_CODEC, b'{"v":1,"t":1e400}', "clock.t: expected a finite number, got inf"),
    (NAV_STATE_CODEC, OLD_STATE.replace(b'"battery":0.97', b'"battery":"full"'), "state.robot_state.battery: expected a finite number, got 'full'"),
    (NAV_STATE_CODEC, OLD_STATE.replace(b'"goals":{', b'"goals":[').replace(b"}}}", b"}]}"), "state.goals: expected a JSON object"),
    (NAV_STATE_CODEC, b'{"v":1,"robot":"robot1","t":1,"robot_state":{"pose":null},"goals":{}}', "state.robot_state.linear_velocity: missing"),
]  # fmt: skip


@pytest.mark.parametrize(("codec", "payload", "error"), NAV_ERRORS)
def test_malformed_navigation_messages_name_the_field(codec: Any, payload: bytes, error: str) -> None:
    with pytest.raises(ValueError) as err:
        codec.decode(payload)
    assert str(err.value).startswith(error), str(err.value)


def test_a_malformed_goal_state_names_its_goal_id_and_only_its_own() -> None:
    state = NAV_STATE_CODEC.decode(OLD_STATE.replace(b'"status":"aborted"', b'"status":"lost"'))
    assert state.goal_state(EXECUTING.goal_id) == EXECUTING  # another client's goal: fine
    with pytest.raises(ValueError) as err:
        state.goal_state(ABORTED.goal_id)
    assert str(err.value).startswith(
        "state.goals['/robot1@3fa29c01#6'].status: unknown value 'lost' (expected one of pending, executing, "
    )
    with pytest.raises(KeyError):
        state.goal_state("nobody")


# ----------------------------------------------------------------------------- sending


def test_sending_a_non_finite_number_raises_naming_the_field() -> None:
    cases: list[tuple[Any, str]] = [
        (lambda: msgspec.structs.replace(STATUS, battery=math.nan).to_json(), "status.battery"),
        (lambda: msgspec.structs.replace(STATUS, pose=(math.inf, 0.0, 0.0)).to_json(), "status.pose[0]"),
        (lambda: msgspec.structs.replace(GRANT, poses=(Pose2D(0, math.nan), Pose2D(1, 1))).to_json(), "grant.poses[0][1]"),
        (lambda: msgspec.structs.replace(PATROL, charger=Pose2D(math.inf, 0)).to_json(), "task.charger[0]"),
        (lambda: goal_to_dict(Wait(math.nan)), "goal.duration_s"),
        (lambda: ClockMsg(math.inf).to_json(), "clock.t"),
    ]  # fmt: skip
    for send, field in cases:
        with pytest.raises(ValueError, match=rf"^{re.escape(field)}: expected a finite"):
            send()


def test_a_wrongly_typed_status_is_caught_when_a_number_is_not_a_number() -> None:
    with pytest.raises(ValueError, match=r"^status\.t: expected a finite number, got 'soon'$"):
        msgspec.structs.replace(STATUS, t="soon").to_json()  # type: ignore[arg-type]  # on purpose


def test_inconsistent_orders_are_refused_on_send() -> None:
    with pytest.raises(ValueError, match=r"^task\.poses: a patrol task needs at least one pose$"):
        TaskMessage("p-1", "patrol", "robot1").to_json()
    with pytest.raises(
        ValueError,
        match=r"^task\.kind: 'dance' is not one of patrol, pick, go_to, inspection, charge, park, idle$",
    ):
        TaskMessage("p-1", "dance").to_json()
    with pytest.raises(TypeError, match="not a navigation goal"):
        goal_to_dict("go there")  # type: ignore[arg-type]  # on purpose


def test_numpy_scalars_from_the_simulator_are_sent_as_numbers() -> None:
    rec = msgspec.structs.replace(
        STATUS, pose=(np.float32(1.5), np.float64(2.0), 0.0), laps=np.int64(3), charging=np.bool_(True)
    )
    back = StatusRecord.from_json(rec.to_json())
    assert (back.pose, back.laps, back.charging) == ((1.5, 2.0, 0.0), 3, True)
    g = msgspec.structs.replace(GRANT, poses=(Pose2D(np.float64(1.0), 2.0), Pose2D(3.0, np.float32(2.0))))
    assert Grant.from_json(g.to_json()).poses == (Pose2D(1.0, 2.0), Pose2D(3.0, 2.0))


@dataclass(frozen=True)
class _ConfigPick:  # like fleet.config.PickTask: more fields than the wire carries
    name: str
    shelf: Pose2D
    drop: Pose2D
    dwell_s: float = 5.0
    robot: str | None = "robot9"


def test_any_pick_like_object_is_sent_as_a_pick_order() -> None:
    msg = TaskMessage("k-1", "pick", "robot1", pick=_ConfigPick("p", Pose2D(1, 2), Pose2D(3, 4)))
    back = TaskMessage.from_json(msg.to_json())
    assert back.pick == PickOrder("p", Pose2D(1, 2), Pose2D(3, 4), 5.0)
    assert json.loads(msg.to_json())["pick"] == {
        "name": "p",
        "shelf": [1, 2, 0],
        "drop": [3, 4, 0],
        "dwell_s": 5,
    }


def test_feedback_drops_non_finite_numbers_instead_of_failing() -> None:
    st = GoalState("g", "wait", GoalStatus.EXECUTING, Feedback(time_left_s=math.inf, navigation_time_s=1.0))
    state = NAV_STATE_CODEC.decode(NavState.build("robot1", 1.0, ROBOT_STATE, {"g": st}).to_json())
    assert state.goal_state("g").feedback == Feedback(navigation_time_s=1.0)


# ----------------------------------------------------------------------------- properties

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
text = st.text(max_size=20)
counts = st.integers(min_value=0, max_value=2**53)  # the wire bound of every count
names = st.from_regex(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,20}", fullmatch=True)
records = st.builds(
    StatusRecord,
    robot=names, ns=text, t=finite, pose=st.none() | st.tuples(finite, finite, finite), battery=finite,
    charging=st.booleans(), stuck=st.booleans(), bt=text, leaf=text, mode=text, task_id=st.none() | text,
    laps=counts, progress=finite, distance_m=finite, collisions=counts, seq=counts, picks_done=counts,
)  # fmt: skip
json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=10),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
    max_leaves=20,
)
DECODERS = [
    StatusRecord.from_json,
    TaskMessage.from_json,
    Grant.from_json,
    GOAL_REQUEST_CODEC.decode,
    CANCEL_REQUEST_CODEC.decode,
    NAV_STATE_CODEC.decode,
    CLOCK_CODEC.decode,
]


@settings(max_examples=200, deadline=None)
@given(records)
def test_every_valid_status_record_round_trips(rec: StatusRecord) -> None:
    assert StatusRecord.from_json(rec.to_json()) == rec


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300) | st.builds(lambda v: json.dumps(v).encode(), json_values))
def test_any_payload_decodes_or_raises_value_error(payload: bytes) -> None:
    for decode in DECODERS:
        try:
            decode(payload)
        except ValueError as e:
            assert ": " in str(e)


@settings(max_examples=200, deadline=None)
@given(st.dictionaries(st.sampled_from(sorted(STATUS.to_dict())), json_values, max_size=5))
def test_a_status_with_fields_replaced_by_anything_decodes_or_raises_value_error(
    changes: dict[str, Any],
) -> None:
    payload = json.dumps({**STATUS.to_dict(), **changes}).encode()
    try:
        rec = StatusRecord.from_json(payload)
    except ValueError as e:
        field = str(e).split(":", 1)[0]
        assert field == "payload" or field.startswith("status"), str(e)
    else:
        assert StatusRecord.from_json(rec.to_json()) == rec
