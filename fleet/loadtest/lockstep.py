"""The lockstep protocol between a load test's main process and its agent workers.

``fleet loadtest --workers K`` keeps the simulator, the coordinator and traffic management in
the main process and runs the agents in ``K`` worker processes (:mod:`fleet.loadtest.worker`)
that meet it on the Zenoh router (its endpoint; other machines may connect to it). The run
advances in lockstep, so a seeded run makes the same decisions whatever ``K``:

1. at every agent tick the main process sends each worker a :class:`TickMsg` on
   ``fleet/loadtest/<run>/w<i>/tick``: the simulated time, the robot state of each of the
   worker's robots, the state of every goal the worker watches, and the orders and traffic
   grants the coordinator gave its robots since the last tick;
2. the worker ticks its agents once each against :class:`MirrorBackend`\\ s that answer from
   that snapshot. A goal sent or canceled is a call to the main process (a Zenoh query on
   ``fleet/loadtest/<run>/nav``, :class:`NavCall` -> :class:`NavReply`): the simulator starts
   or cancels it at once, as in one process, and the reply carries the goal's and the robot's
   state after it;
3. the worker answers with a :class:`DoneMsg` on ``fleet/loadtest/<run>/w<i>/done``: every
   agent's status record of this tick (for the coordinator) and the goal ids to watch;
4. with every worker's answer in, the main process feeds the records to the coordinator in
   robot order, runs its cycle and steps the simulator to the next tick.

Nothing of the simulator moves while the agents tick (in one process neither), the agents'
inputs are bit-identical (MessagePack carries floats exactly) and the coordinator sees the
records in the same order, so the run is the same run. The workers also publish their robots'
statuses on the bus as usual (batched, at ``bus.status_hz``), for ``fleet status`` and
dashboards attached to the router.

Delivery: ticks and answers go with congestion control *drop*; a tick not answered within a
few seconds is sent again and a worker answers a tick it already did from its last answer, and
a goal call not answered is asked again and served once (its number, :attr:`NavCall.call`), so
a dropped message costs a few seconds, never a step of the run.

Every message is MessagePack decoded into typed structs (``fleet.types`` dataclasses inside);
a malformed one raises :class:`ValueError` in the receiver, which ends the run with an error
(a lockstep run cannot skip a tick)."""

from __future__ import annotations

import numbers
from collections.abc import Callable
from typing import Final, TypeVar

import msgspec
from msgspec import Struct

from fleet.bus.keys import LOCKSTEP_PREFIX
from fleet.messages import StatusRecord
from fleet.messages.nav import GoalMsg, goal_message
from fleet.types import Goal, GoalState, GoalStatus, RobotState

#: Keep at most this many finished goal states per robot in a worker's mirror.
KEEP_FINISHED = 16

#: The key space of a load test's lockstep protocol (``<run>`` names the run).
PREFIX: Final = LOCKSTEP_PREFIX

TERMINAL: Final = frozenset(
    {GoalStatus.SUCCEEDED, GoalStatus.ABORTED, GoalStatus.CANCELED, GoalStatus.REJECTED}
)


def spec_key(run: str) -> str:
    """Where the main process answers with the :class:`RunSpec`."""
    return f"{PREFIX}/{run}/spec"


def nav_key(run: str) -> str:
    """Where the main process answers goal calls (:class:`NavCall`)."""
    return f"{PREFIX}/{run}/nav"


def tick_key(run: str, worker: int) -> str:
    return f"{PREFIX}/{run}/w{worker}/tick"


def done_key(run: str, worker: int) -> str:
    return f"{PREFIX}/{run}/w{worker}/done"


class RunSpec(Struct, frozen=True):
    """What a worker needs to build the same agents: the load test's arguments (it generates
    the same warehouse from them) and the robots of each worker (contiguous slices of the
    config's robots, in order)."""

    robots: int
    seed: int
    tick_hz: float
    status_hz: float
    status_max_period_s: float | None
    step_s: float | None
    route_copies: int | None
    traffic: bool
    assignment: list[list[str]]


class TickMsg(Struct, frozen=True):
    """Main -> worker: tick ``k`` at simulated time ``t``. ``states``: the worker's robots'
    states in its order; ``goals``: ``[goal id, state]`` of the watched goals; ``orders`` and
    ``grants``: JSON of :class:`~fleet.messages.TaskMessage` / :class:`~fleet.messages.Grant`
    (in the coordinator's order); ``end``: stop (send the final :class:`DoneMsg`)."""

    k: int
    t: float
    states: list[RobotState]
    goals: list[tuple[str, GoalState]]
    orders: list[bytes]
    grants: list[bytes]
    end: bool = False


class AgentStats(Struct, frozen=True):
    """What the run report needs of an agent (sent once, with the last :class:`DoneMsg`)."""

    robot: str
    charges: int
    min_battery: float
    mode_ticks: dict[str, int]
    safety_stops: int


class DoneMsg(Struct, frozen=True):
    """Worker -> main: tick ``k`` done (``k == -1``: the worker is ready). ``records``: one
    status record per agent, in the worker's order; ``watch``: goal ids whose state the next
    tick must carry; ``stats``: filled on the answer to the ``end`` tick."""

    worker: int
    k: int
    records: list[StatusRecord]
    watch: list[str]
    stats: list[AgentStats] = []


class NavCall(Struct, frozen=True):
    """Worker -> main (a query): ``op`` ``send`` (``goal`` for robot ``namespace``), ``cancel``
    or ``state`` (of ``goal_id``). ``call`` numbers the calls of one ``worker``: a call asked
    again (its answer was late) is answered again, not served twice."""

    op: str
    namespace: str
    goal: GoalMsg | None = None
    goal_id: str = ""
    worker: int = -1
    call: int = 0


class NavReply(Struct, frozen=True):
    """The answer to a :class:`NavCall`: the goal id and its state after the call (``None``:
    an unknown id, ``error`` says why), and the robot's state after it."""

    goal_id: str
    state: GoalState | None
    robot: RobotState
    error: str = ""


def _enc_hook(obj: object) -> object:
    # numpy scalars reach the encoder from the simulator's arrays
    if isinstance(obj, numbers.Integral):
        return int(obj)
    if isinstance(obj, numbers.Real):
        return float(obj)
    raise TypeError(f"cannot encode {type(obj).__name__}")


_ENC: Final = msgspec.msgpack.Encoder(enc_hook=_enc_hook)


def encode(msg: Struct) -> bytes:
    """MessagePack of a protocol message."""
    return _ENC.encode(msg)


M = TypeVar("M", bound=Struct)


def decoder(cls: type[M]) -> Callable[[bytes], M]:
    """A strict decoder of ``cls``: ValueError naming the field for a malformed payload."""
    dec = msgspec.msgpack.Decoder(cls)

    def decode(data: bytes) -> M:
        try:
            return dec.decode(data)
        except (msgspec.ValidationError, msgspec.DecodeError) as e:
            raise ValueError(f"{cls.__name__}: {e}") from None

    return decode


def nav_call(op: str, namespace: str, goal: Goal | None = None, goal_id: str = "") -> NavCall:
    return NavCall(op, namespace, None if goal is None else goal_message(goal), goal_id)


class MirrorBackend:
    """A worker's :class:`~fleet.navigation.NavigationBackend` of one robot: reads come from
    the tick's snapshot; sending and canceling a goal (and reading a goal the snapshot lacks)
    call the main process (``call``), whose simulator acts at once."""

    def __init__(self, namespace: str, call: Callable[[NavCall], NavReply]) -> None:
        self._namespace = namespace
        self._call: Callable[[NavCall], NavReply] | None = call
        self._state: RobotState | None = None
        self._goals: dict[str, GoalState] = {}

    @property
    def namespace(self) -> str:
        return self._namespace

    def update(self, state: RobotState, goals: dict[str, GoalState]) -> None:
        """The tick's snapshot: the robot's state and the states of its watched goals."""
        self._state = state
        self._goals.update(goals)
        done = [g for g, s in self._goals.items() if s.status in TERMINAL]
        for gid in done[: max(0, len(done) - KEEP_FINISHED)]:
            del self._goals[gid]

    def detach(self) -> None:
        """The run is over: calls no longer reach the simulator (canceling the goals of closing
        agents is moot there, as it is after a one-process run's report)."""
        self._call = None

    def _do(self, call: NavCall) -> NavReply | None:
        return None if self._call is None else self._call(call)

    def watch(self) -> list[str]:
        """Goal ids whose state may still change."""
        return [g for g, s in self._goals.items() if s.status not in TERMINAL]

    def _take(self, reply: NavReply) -> None:
        self._state = reply.robot
        if reply.state is not None:
            self._goals[reply.goal_id] = reply.state

    def send_goal(self, goal: Goal) -> str:
        from fleet.errors import BackendError

        reply = self._do(nav_call("send", self._namespace, goal))
        if reply is None or reply.error:
            raise BackendError(reply.error if reply is not None else f"{self._namespace}: the run is over")
        self._take(reply)
        return reply.goal_id

    def goal_state(self, goal_id: str) -> GoalState:
        st = self._goals.get(goal_id)
        if st is not None:
            return st
        reply = self._do(nav_call("state", self._namespace, goal_id=goal_id))
        if reply is None or reply.state is None:
            raise KeyError(goal_id)
        self._take(reply)
        return reply.state

    def cancel_goal(self, goal_id: str) -> None:
        reply = self._do(nav_call("cancel", self._namespace, goal_id=goal_id))
        if reply is not None:
            self._take(reply)

    def robot_state(self) -> RobotState:
        if self._state is None:
            raise KeyError(f"{self._namespace}: no state yet")
        return self._state
