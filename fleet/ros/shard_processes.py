"""``fleet sim-ros --shards K``: the namespaced robots served from K processes.

A parent process (no rclpy context of its own) starts K children, each the ordinary server
(``python -m fleet.ros.nav2_server CONFIG ... --shard-of I/K``) for a share of the config's
robots: robot ``i`` (1-based, in the config's order after ``--robots``) goes to shard
``(i - 1) % K + 1``. Each child has its own rclpy context (DDS participant), executor and
**its own simulator holding only its robots**:

* robots of different shards do not see each other: no robot-robot avoidance, no contact
  (collision) events between them; obstacles, the map and everything within a shard are as in
  one process. Use one shard where robots must interact across the whole fleet;
* each shard's simulated clock starts when that shard is ready, so stamps of different shards
  differ by their start-up skew (a few wall seconds times ``--speed``);
* shard 1's world node is ``/fleet_sim`` (the others ``/fleet_sim_shard2`` ...): ``/map`` is
  published by every shard (the same map), ``/tf`` and ``/diagnostics`` each carry the shard's
  own robots.

Stopping: SIGINT / SIGTERM to the parent is passed on to every shard (Ctrl-C in a terminal
reaches them all anyway, they share its process group); a shard still running after
:data:`STOP_S` is killed. Each child asks the kernel for SIGTERM when its parent dies
(``PR_SET_PDEATHSIG``), so even a killed parent leaves no shard behind. A shard that exits
on its own with an error stops the others (exit 1). The ready file (``--ready-file``) is
written once every shard is ready: ``pid`` (the parent), ``robots``, ``create_s`` (wall s from
the parent's start), ``shards``, ``participants`` (per shard), ``shard_pids``,
``shard_create_s``, ``shard_domain_ids``. ``--truth`` / ``--plot`` merge the shards' ground truth.

``--shard-domains`` puts shard ``I`` on ROS domain ``ROS_DOMAIN_ID + I - 1``: FastDDS's simple
discovery then no longer makes every shard match every other shard's endpoints (its cost grows
with the endpoints on both sides), but a client sees a shard's robots only from a participant
on that shard's domain (``make_ros_backends(..., domain_id=...)`` per shard; RViz per domain).

Imports nothing from ROS (the parent stays a small process).
"""

from __future__ import annotations

import ctypes
import faulthandler
import json
import logging
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING

from fleet.ros.launch import ReadyInfo, write_ready

if TYPE_CHECKING:
    from fleet.config.model import FleetConfig

log = logging.getLogger(__name__)

#: Environment variable naming the parent's pid in each shard (a shard whose parent is
#: already gone at start exits at once).
PARENT_VAR = "FLEET_SIM_ROS_PARENT"
#: Wall seconds a shard gets to stop after SIGINT before it is killed.
STOP_S = 10.0
#: Poll period (wall s) of the parent's wait for its shards.
POLL_S = 0.05
#: Exit status after SIGINT / SIGTERM (as one process: docs/cli.md).
EXIT_INTERRUPTED = 130
#: Options of the parent that its shards do not get (the parent handles them).
PARENT_ONLY = ("--shards", "--ready-file", "--truth", "--plot", "--shard-domains")
#: Options of :data:`PARENT_ONLY` that take no value.
FLAGS = ("--shard-domains",)
#: Highest ROS domain id (ROS 2; FastDDS advises at most 101 on Linux, ephemeral ports).
MAX_DOMAIN_ID = 232
_PR_SET_PDEATHSIG = 1


def shard_of(text: str) -> tuple[int, int]:
    """``"I/K"`` (``--shard-of``, 1-based) as ``(I - 1, K)``; ``ValueError`` if malformed."""
    i, _, k = text.partition("/")
    if not (i.isdigit() and k.isdigit() and 1 <= int(i) <= int(k)):
        raise ValueError(f"--shard-of must be I/K with 1 <= I <= K, got {text!r}")
    return int(i) - 1, int(k)


def child_argv(argv: list[str]) -> list[str]:
    """``argv`` of ``fleet sim-ros`` without the options only the parent handles
    (:data:`PARENT_ONLY`, as ``--opt VALUE`` or ``--opt=VALUE``)."""
    out: list[str] = []
    it = iter(argv)
    for a in it:
        if a in FLAGS:
            continue
        if a in PARENT_ONLY:
            next(it, None)
        elif not a.startswith(tuple(f"{o}=" for o in PARENT_ONLY)):
            out.append(a)
    return out


def follow_parent() -> None:
    """In a shard: ask for SIGTERM when the parent dies (Linux ``prctl``; elsewhere nothing),
    and exit at once (status 130) if the parent named by :data:`PARENT_VAR` is already gone."""
    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
    except (OSError, AttributeError):  # not Linux: the parent's own stop must do
        log.debug("prctl(PR_SET_PDEATHSIG) unavailable")
    faulthandler.register(signal.SIGUSR1, all_threads=True)
    parent = os.environ.get(PARENT_VAR)
    if parent and os.getppid() != int(parent):
        raise SystemExit(EXIT_INTERRUPTED)


class _Stop:
    """Set by SIGINT / SIGTERM in the parent."""

    def __init__(self) -> None:
        self.requested = False

    def __call__(self, _sig: int, _frame: FrameType | None) -> None:
        self.requested = True


def run_shards(
    cfg: FleetConfig,
    argv: list[str],
    count: int,
    *,
    ready_file: str | None = None,
    truth: str | None = None,
    plot: str | None = None,
    domains: bool = False,
) -> int:
    """The parent of ``count`` shard processes serving ``cfg``'s robots (``argv``: the
    command's arguments, passed on without :data:`PARENT_ONLY`). Returns the exit status: 0
    when every shard ended its ``--duration``, 130 after SIGINT / SIGTERM, 1 when a shard
    failed, 2 when there are more shards than robots. ``domains``: shard ``I`` on ROS domain
    ``ROS_DOMAIN_ID + I - 1`` (``--shard-domains``)."""
    if count > len(cfg.robots):
        print(f"error: --shards {count} is more than the {len(cfg.robots)} robots", file=sys.stderr)
        return 2
    stop = _Stop()
    faulthandler.register(signal.SIGUSR1, all_threads=True)  # a hung run's stacks on demand
    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGTERM, stop)
    t0 = time.monotonic()
    base = int(os.environ.get("ROS_DOMAIN_ID", "0") or 0)
    ids = [base + i if domains else base for i in range(count)]
    if ids[-1] > MAX_DOMAIN_ID:
        print(
            f"error: --shard-domains needs domains {base}..{ids[-1]}; at most {MAX_DOMAIN_ID}",
            file=sys.stderr,
        )
        return 2
    with tempfile.TemporaryDirectory(prefix="fleet-sim-ros-shards-") as tmp:
        files = [Path(tmp) / f"ready{i}.json" for i in range(count)]
        truths = [Path(tmp) / f"truth{i}.json" for i in range(count)]
        env = {**os.environ, PARENT_VAR: str(os.getpid())}
        procs: list[subprocess.Popen[bytes]] = []
        try:
            for i in range(count):
                extra = ["--shard-of", f"{i + 1}/{count}", "--ready-file", str(files[i])]
                extra += ["--domain-id", str(ids[i])] if domains else []
                extra += ["--truth", str(truths[i])] if truth or plot else []
                cmd = [sys.executable, "-m", "fleet.ros.nav2_server", *child_argv(argv), *extra]
                procs.append(subprocess.Popen(cmd, env=env))
            failed = _watch(procs, files, stop, cfg, ready_file, t0)
        finally:
            _stop_all(procs)
        if truth or plot:
            _merge_truth(cfg, truths, truth, plot)
    if stop.requested:
        return EXIT_INTERRUPTED
    if failed is not None:
        print(f"error: sim-ros shard {failed + 1}/{count} exited with {procs[failed].returncode}; "
              "the other shards were stopped", file=sys.stderr)  # fmt: skip
        return 1
    print(f"[sim-ros] all {count} shards stopped", flush=True)
    return 0


def _watch(
    procs: list[subprocess.Popen[bytes]],
    files: list[Path],
    stop: _Stop,
    cfg: FleetConfig,
    ready_file: str | None,
    t0: float,
) -> int | None:
    """Wait until a signal, every shard ended (status 0), or a shard failed (its index is
    returned); write the ready file once every shard is ready."""
    ready = False
    while not stop.requested:
        codes = [p.poll() for p in procs]
        bad = [i for i, c in enumerate(codes) if c not in (None, 0)]
        if bad:
            return bad[0]
        if all(c is not None for c in codes):
            return None
        if not ready and all(f.exists() for f in files):
            ready = True
            _announce(procs, files, cfg, ready_file, time.monotonic() - t0)
        time.sleep(POLL_S)
    return None


def _announce(
    procs: list[subprocess.Popen[bytes]],
    files: list[Path],
    cfg: FleetConfig,
    ready_file: str | None,
    took: float,
) -> None:
    infos = [json.loads(f.read_text()) for f in files]
    info: ReadyInfo = {
        "pid": os.getpid(),
        "robots": [r.namespace for r in cfg.robots],
        "create_s": round(took, 3),
        "domain_id": os.environ.get("ROS_DOMAIN_ID", "0"),
        "shards": len(procs),
        "participants": infos[0]["participants"],
        "shard_pids": [p.pid for p in procs],
        "shard_create_s": [i["create_s"] for i in infos],
        "shard_domain_ids": [int(i["domain_id"]) for i in infos],
    }
    print(
        f"[sim-ros] serving {len(cfg.robots)} robots from {len(procs)} shard processes (ready in "
        f"{took:.1f} s; robots of different shards do not see each other); Ctrl-C stops",
        flush=True,
    )
    if ready_file:
        write_ready(ready_file, info)


def _stop_all(procs: list[subprocess.Popen[bytes]]) -> None:
    """SIGINT every running shard, wait up to :data:`STOP_S`, then SIGKILL what is left."""
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    deadline = time.monotonic() + STOP_S
    for p in procs:
        try:
            p.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            log.warning("sim-ros shard %d did not stop within %.0f s: killed", p.pid, STOP_S)
            p.kill()
            p.wait()


def _merge_truth(cfg: FleetConfig, truths: list[Path], truth: str | None, plot: str | None) -> None:
    """One ground-truth file (and plot) from the shards' (``write_truth``'s format)."""
    parts = [json.loads(p.read_text()) for p in truths if p.exists()]
    robots = {ns: r for part in parts for ns, r in part["robots"].items()}
    merged = {"t": max((p["t"] for p in parts), default=0.0), "robots": robots}
    if truth:
        Path(truth).write_text(json.dumps(merged))
        print(f"[sim-ros] ground truth: {truth}", flush=True)
    if plot:
        from fleet.viz.plot import plot_run

        traj = {
            r.name: [(t, x, y) for t, x, y in robots[r.namespace]["trajectory"]]
            for r in cfg.robots
            if r.namespace in robots
        }
        plot_run(
            cfg, traj, plot, title=f"{cfg.name} (fleet sim-ros, {len(truths)} shards, true trajectories)"
        )
        print(f"[sim-ros] plot: {plot}", flush=True)
