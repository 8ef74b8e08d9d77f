"""The server's DDS participants: the robots' nodes spread over several rclpy contexts.

One rclpy :class:`~rclpy.context.Context` is one DDS participant. :class:`Shards` makes ``K``
contexts, each with its own executor; the caller spins the first one (the world node's), a
thread spins each of the others, and every callback of every executor runs holding one lock,
so the simulator behind them is still touched by one callback at a time (only the waiting
for work runs in parallel). Imported by the server only.

Measured here (``docs/ros.md``, "Scale"): with FastDDS's simple discovery, spreading 100
robots over 4 participants (and the client over 4) made discovery slower, not faster: every
participant announces all its endpoints to every other, so the discovery traffic grows with
the participants. The default is one.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import rclpy
from rclpy.context import Context
from rclpy.executors import (
    ConditionReachedException,
    Executor,
    ShutdownException,
    SingleThreadedExecutor,
    TimeoutException,
    TimeoutObject,
)
from rclpy.signals import SignalHandlerOptions

from fleet.ros.executors import make_executor


class LockedExecutor(SingleThreadedExecutor):
    """A single-threaded executor whose callbacks run holding ``lock`` (its wait for work
    does not)."""

    def __init__(self, lock: threading.RLock, *, context: Context) -> None:
        super().__init__(context=context)
        self._callback_lock = lock

    def _spin_once_impl(
        self,
        timeout_sec: float | TimeoutObject | None = None,
        wait_condition: Callable[[], bool] = lambda: False,
    ) -> None:
        try:
            handler, _, _ = self.wait_for_ready_callbacks(timeout_sec, None, wait_condition)
        except (ShutdownException, TimeoutException, ConditionReachedException):
            return
        with self._callback_lock:
            handler()
        if handler.exception() is not None:
            raise handler.exception()
        handler.result()


class Shards:
    """``count`` rclpy contexts with an executor each (see the module docstring).

    Args:
        count: number of contexts (DDS participants), at least 1.
        domain_id: ROS domain of the contexts (default: ``ROS_DOMAIN_ID``).
        context: use this initialized context as the only one (``count`` must be 1); it is
            not shut down by :meth:`close`.
    """

    def __init__(self, count: int, domain_id: int | None = None, context: Context | None = None) -> None:
        if count < 1 or (context is not None and count != 1):
            raise ValueError(f"shards must be >= 1 (and 1 with a context passed in), got {count}")
        self._owns = context is None
        self.contexts: list[Context] = [context] if context is not None else []
        while len(self.contexts) < count:
            ctx = Context()
            rclpy.init(context=ctx, domain_id=domain_id, signal_handler_options=SignalHandlerOptions.NO)
            self.contexts.append(ctx)
        #: Held while any callback of any shard runs.
        self.lock = threading.RLock()
        # one shard: rclpy's own executor, untouched (the demo over ROS lost 60 % of its laps
        # at 4x real time with the locked one even alone; not understood yet)
        self.executors: list[Executor] = (
            [make_executor(self.contexts[0])]
            if count == 1
            else [LockedExecutor(self.lock, context=c) for c in self.contexts]
        )
        self._threads: list[threading.Thread] = []
        self._stop = threading.Event()

    def start(self) -> None:
        """Spin every shard but the first in a thread of its own (daemon threads)."""
        for k, ex in enumerate(self.executors[1:], start=1):
            t = threading.Thread(target=self._spin, args=(ex,), name=f"sim-ros-shard-{k}", daemon=True)
            t.start()
            self._threads.append(t)

    def _spin(self, ex: Executor) -> None:
        while not self._stop.is_set() and ex.context.ok():
            ex.spin_once(timeout_sec=0.1)

    def spin_once(self, timeout_s: float) -> None:
        """Run at most one ready callback of the first shard (the caller's thread)."""
        self.executors[0].spin_once(timeout_sec=timeout_s)

    def ok(self) -> bool:
        return all(c.ok() for c in self.contexts)

    def stop(self) -> None:
        """Stop the shard threads (waits up to 2 s for each)."""
        self._stop.set()
        for t in self._threads:
            t.join(timeout=2.0)
        self._threads.clear()

    def close(self) -> None:
        """Stop the threads, shut the executors down and the contexts this object made."""
        self.stop()
        for ex in self.executors:
            ex.shutdown(timeout_sec=1.0)
        if self._owns:
            for c in self.contexts:
                if c.ok():
                    rclpy.shutdown(context=c)
