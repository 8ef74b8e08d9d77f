#!/usr/bin/env python3
"""How many namespaced Nav2 robots one ROS 2 process (``fleet sim-ros``) can serve, and what
it costs: a benchmark, not a test.

For each robot count N (and interface profile, shard count, CPU hogs): start ``python -m
fleet.ros.nav2_server CONFIG --robots N --shards K`` in a child process (K > 1: a parent and K
shard processes, each serving and simulating N/K robots) and measure
  * launch_s: from starting the server until it (every shard) is ready;
  * create_s: creating the N facades (nodes, action servers, services) in the server (with
    shards: the slowest shard's; launch_s includes Python's start-up);
  * server_rss_mb: the server's resident memory once ready (the parent and its shards);
  * client_create_s: creating N RosNavigationBackends in this process (one lean node each,
    one rclpy context, i.e. one DDS participant: "a client"; with --client-actions nav each
    makes only the two navigators' action clients at start);
  * discover_s: from the same start until every robot's 7 action servers are discovered (read
    from the graph node by node: fleet.ros.action_graph);
  * active_s: from the same start until every robot's navigator answers ``active`` on its
    lifecycle ``get_state`` service (the server has discovered this client too);
  * wait_all_s: sending one goal to every robot at once (--goal wait: Wait(0.5 s); here:
    NavigateToPose to where the robot stands) until all SUCCEEDED (the goal round trip under
    load, at --speed 1); wait_ok of N succeeded, wait_other how the others ended;
  * answered_s: from the client's start until every robot answered its goal (discovery,
    navigators active, the goal round trip); total_s: launch_s + answered_s (a cold start);
  * client_cpu_s, client_executor_cpu_s, server_cpu_s: CPU seconds of this process, of its
    executor threads, and of every server process, from the client's start to discovery;
  * client_rss_mb: this process's resident memory growth;
  * load: the 1-minute load average at the row's start and end.
--hog H runs H busy loops (one Python process each, not niced) beside the row: the same
fleet on a machine that is busy with something else.
Every row runs under a hang guard (--row-limit; RowGuard): a row that does not end prints
every process's stacks and a clear error and the bench exits 3.
Claimed private ROS domains (fleet.ros.domains; one per shard of the largest --shards), loopback, the fleet's FastDDS discovery profile (``FLEET_ROS_DISCOVERY=scale``
in the environment: the 20 s-lease profile for both sides; the row's profile_file names it).

Usage: python bench/bench_ros_scale.py [--robots 10,50,100] [--profile lean,full] [--shards 1,2,4]
       [--hog 0,1] [--domains same,shard]
       [--executor single,events] [--client-actions all,nav] [--goal wait|here]
       [--managers lazy,eager] [--row-limit S]
       [--discovery-server]
       [--config configs/warehouse_patrol_30.yaml] [--json out/bench_ros_scale.json]
"""

from __future__ import annotations

import argparse
import contextlib
import faulthandler
import itertools
import json
import os
import re
import signal
import socket
import subprocess
import sys
import sysconfig
import threading
import time
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from fleet.ros.domains import claim_domains  # noqa: E402
from fleet.ros.env import apply_ros_env_defaults  # noqa: E402
from fleet.ros.launch import ServerProcess  # noqa: E402


def cpu_s(pid: int | str = "self", tid: int | None = None) -> float:
    """CPU seconds (user + system) a process (or one of its threads) has used so far."""
    path = f"/proc/{pid}/task/{tid}/stat" if tid is not None else f"/proc/{pid}/stat"
    try:
        fields = Path(path).read_text().rpartition(")")[2].split()
    except FileNotFoundError:
        return float("nan")
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def rss_mb(pid: int | str = "self") -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


@contextlib.contextmanager
def discovery_server(timeout_s: float = 30.0) -> Iterator[str]:
    """FastDDS's discovery server as the ROS wheels ship it (``fast-discovery-server-*`` next
    to this interpreter; its libraries in the venv's ``lib`` and ``ros_fastrtps.libs``) on a
    free loopback port; ``ROS_DISCOVERY_SERVER`` points this process and its children at it."""
    exe = sorted(Path(sys.executable).parent.glob("fast-discovery-server-*"))
    if not exe:
        raise SystemExit("error: no fast-discovery-server next to this Python (make setup-ros)")
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    venv = Path(sys.executable).parent.parent
    libs = [str(venv / "lib"), str(Path(sysconfig.get_paths()["purelib"]) / "ros_fastrtps.libs")]
    env = {**os.environ, "LD_LIBRARY_PATH": os.pathsep.join([*libs, os.environ.get("LD_LIBRARY_PATH", "")])}
    cmd = [str(exe[-1]), "-i", "0", "-l", "127.0.0.1", "-p", str(port)]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + timeout_s
        assert proc.stdout is not None
        while "Server is running" not in proc.stdout.readline():
            if proc.poll() is not None or time.monotonic() > deadline:
                raise SystemExit(f"error: {' '.join(cmd)} did not start")
        os.environ["ROS_DISCOVERY_SERVER"] = f"127.0.0.1:{port}"
        yield os.environ["ROS_DISCOVERY_SERVER"]
    finally:
        os.environ.pop("ROS_DISCOVERY_SERVER", None)
        proc.terminate()
        try:
            proc.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@contextlib.contextmanager
def hogs(count: int) -> Iterator[None]:
    """``count`` busy loops (one Python process each) while the block runs."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(count)]
    try:
        yield
    finally:
        for p in procs:
            p.kill()
            p.wait()


class RowGuard:
    """Hang guard of one row: if the row has not ended after ``limit_s`` (wall s), print a
    clear error, every thread's Python stack of this process (faulthandler) and of each shard
    process (SIGUSR1: ``fleet.ros.shard_processes`` registers faulthandler on it; the stacks
    land in the server's log, printed too), kill the server's process group and exit with
    status 3. A row blocked in C code that holds the GIL starves this watchdog thread: then
    faulthandler's own C thread dumps the stacks ``grace_s`` later and exits (status 1; that
    path cannot stop the server: kill its process group, named in the bench's log, by hand)."""

    def __init__(self, limit_s: float, what: str, grace_s: float = 30.0) -> None:
        self.limit_s = limit_s
        self.what = what
        self.grace_s = grace_s
        #: The row's server, once started (set by :func:`one`).
        self.server: ServerProcess | None = None
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._watch, name="row-guard", daemon=True)

    def __enter__(self) -> RowGuard:
        faulthandler.dump_traceback_later(self.limit_s + self.grace_s, exit=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._done.set()
        faulthandler.cancel_dump_traceback_later()

    def _watch(self) -> None:
        if self._done.wait(self.limit_s):
            return
        print(
            f"error: row {self.what} did not end within {self.limit_s:.0f} s (--row-limit): "
            "hung; the stacks of this process and of the shards follow",
            file=sys.stderr,
            flush=True,
        )
        faulthandler.dump_traceback(all_threads=True)
        srv = self.server
        if srv is not None:
            shards = srv.info.get("shard_pids", [])
            for pid in [*shards, srv.proc.pid] if shards else []:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGUSR1)
            time.sleep(3.0)
            print(f"--- server log (tail) ---\n{srv.log()}", file=sys.stderr, flush=True)
            srv.kill()
        os._exit(3)


def one(
    config: str,
    n: int,
    profile: str,
    timeout_s: float,
    shards: int = 1,
    executor: str = "single",
    client_actions: str = "all",
    goal: str = "wait",
    server_timeout_s: float = 3.0,
    hog: int = 0,
    domains: str = "same",
    guard: RowGuard | None = None,
    managers: str = "lazy",
) -> dict[str, float | int | str]:
    from fleet.ros.backend import BACKEND_KINDS, make_ros_backends
    from fleet.ros.executors import EXECUTOR_VAR
    from fleet.types import Goal, GoalStatus, NavigateToPose, Wait

    os.environ[EXECUTOR_VAR] = executor  # the server child's executor (fleet.ros.executors)
    row: dict[str, float | int | str] = {
        "robots": n,
        "profile": profile,
        "shards": shards,
        "executor": executor,
        "client_actions": client_actions,
        "goal": goal,
        "server_timeout_s": server_timeout_s,
        "hog": hog,
        "domains": domains,
        "managers": managers,
        "load_start": round(os.getloadavg()[0], 1),
    }
    eager = CLIENT_ACTIONS[client_actions] or BACKEND_KINDS
    t_launch = time.monotonic()
    with ServerProcess.for_config(
        config,
        "--robots",
        str(n),
        "--profile",
        profile,
        "--odom-hz",
        "2",
        "--amcl-hz",
        "0.5",
        "--shards",
        str(shards),
        *(["--shard-domains"] if domains == "shard" and shards > 1 else []),
        ready_timeout_s=timeout_s,
    ) as srv:
        if guard is not None:
            guard.server = srv
            print(f"[bench] row server: process group {srv.proc.pid}", file=sys.stderr, flush=True)
        row["launch_s"] = round(time.monotonic() - t_launch, 3)
        row["create_s"] = max(srv.info.get("shard_create_s", [srv.info["create_s"]]))
        time.sleep(0.5)
        pids = [srv.proc.pid, *srv.info.get("shard_pids", [])]
        row["server_rss_mb"] = round(sum(rss_mb(p) for p in pids), 1)
        rss0 = rss_mb()
        t0 = time.monotonic()
        cpu0 = cpu_s(), sum(cpu_s(p) for p in pids)
        names = [f"/robot{i + 1}" for i in range(n)]
        # one client: one participant, whatever the server's shards; with --domains shard one
        # participant per shard, on that shard's domain (robot i in shard (i-1) % K)
        ids = srv.info.get("shard_domain_ids", [int(srv.info["domain_id"])])
        groups = (
            [make_ros_backends(names, eager=eager, server_timeout_s=server_timeout_s)]
            if len(set(ids)) == 1
            else [
                make_ros_backends(
                    names[k::shards], eager=eager, server_timeout_s=server_timeout_s, domain_id=d
                )
                for k, d in enumerate(ids)
            ]
        )
        rb = {ns: g[ns] for g in groups for ns in g.backends}
        if managers == "eager":  # as before: the lifecycle managers' clients made at start
            for g in groups:
                for b in g.backends.values():
                    g.call_soon(b.lifecycle.make_manager_clients)
        row["client_create_s"] = round(time.monotonic() - t0, 3)
        deadline = time.monotonic() + timeout_s
        missing = [m for g in groups for m in g.wait_for_servers(max(0.0, deadline - time.monotonic()))]
        row["discover_s"] = round(time.monotonic() - t0, 3) if not missing else float("nan")
        # where the CPU went from the client's start to discovery: this process, its executor
        # threads (rclpy's Python executor of each participant), the server processes
        row["client_cpu_s"] = round(cpu_s() - cpu0[0], 1)
        row["client_executor_cpu_s"] = round(sum(cpu_s("self", g._thread.native_id) for g in groups), 1)
        row["server_cpu_s"] = round(sum(cpu_s(p) for p in pids) - cpu0[1], 1)
        row["missing"] = len(missing)
        if not missing:
            # every navigator answering its lifecycle get_state (what make_ros_backends(wait_s)
            # waits for before a fleet sends goals): the server has discovered the client too
            inactive = [m for g in groups for m in g.wait_until_active(max(0.0, deadline - time.monotonic()))]
            row["active_s"] = round(time.monotonic() - t0, 3) if not inactive else float("nan")
            row["inactive"] = len(inactive)
        try:
            if not missing:
                t1 = time.monotonic()
                goals: dict[str, Goal] = {
                    ns: Wait(0.5) if goal == "wait" else NavigateToPose(b.robot_state().pose)
                    for ns, b in rb.items()
                }
                ids = {ns: rb[ns].send_goal(g) for ns, g in goals.items()}
                while time.monotonic() - t1 < timeout_s:
                    if all(rb[ns].goal_state(g).status.terminal for ns, g in ids.items()):
                        break
                    time.sleep(0.01)
                states = [rb[ns].goal_state(g) for ns, g in ids.items()]
                ok = sum(st.status is GoalStatus.SUCCEEDED for st in states)
                ends: dict[str, int] = {}
                for st in states:
                    if st.status is not GoalStatus.SUCCEEDED:
                        msg = re.sub(r"/robot\d+", "<robot>", st.error_msg)
                        key = f"{st.status.name}: {msg}"[:120]
                        ends[key] = ends.get(key, 0) + 1
                if ends:
                    row["wait_other"] = json.dumps(ends)
                row["wait_all_s"] = round(time.monotonic() - t1, 3)
                row["wait_ok"] = ok
                row["answered_s"] = round(time.monotonic() - t0, 3)
                row["total_s"] = round(float(row["launch_s"]) + float(row["answered_s"]), 3)
            row["client_rss_mb"] = round(rss_mb() - rss0, 1)
            row["load_end"] = round(os.getloadavg()[0], 1)
        finally:
            for g in groups:
                g.close()
    return row


#: ``--client-actions``: the action clients each robot's backend makes at start (``None``: all
#: seven); every robot's seven servers are still required to count it discovered.
CLIENT_ACTIONS: dict[str, tuple[str, ...] | None] = {
    "all": None,
    "nav": ("navigate_to_pose", "navigate_through_poses"),
}


def summarize(rows: list[dict[str, float | int | str]]) -> None:
    """One line per row: discovery and the cold start, each against the 1-shard row of the
    same robots, profile and hogs (ratios within this run)."""
    print(
        "robots hog shards domains managers | launch  discover  answered  total | client_create client_cpu "
        "executors_cpu server_cpu | discover/1  total/1 | goals"
    )
    for r in rows:
        base = next(
            (b for b in rows if b["shards"] == 1 and all(b[k] == r[k] for k in ("robots", "hog", "profile"))),
            None,
        )

        def ratio(key: str, row: dict[str, float | int | str] = r, b: object = base) -> str:
            if not isinstance(b, dict) or key not in row or key not in b:
                return "-"
            return f"{float(row[key]) / float(b[key]):.2f}"

        def sec(key: str, row: dict[str, float | int | str] = r) -> str:
            return f"{float(row[key]):7.1f}" if key in row else "      -"

        print(
            f"{r['robots']:6} {r['hog']:3} {r['shards']:6} {r['domains']:>7} {r.get('managers', '-'):>8} | "
            f"{sec('launch_s')} {sec('discover_s')}   {sec('answered_s')} {sec('total_s')} | "
            f"{sec('client_create_s'):>13} {sec('client_cpu_s'):>10} {sec('client_executor_cpu_s'):>13} "
            f"{sec('server_cpu_s'):>10} | {ratio('discover_s'):>10} {ratio('total_s'):>8} | "
            f"{r.get('wait_ok', 0)}/{r['robots']}"
        )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robots", default="10,50,100")
    ap.add_argument("--profile", default="lean,full")
    ap.add_argument("--config", default=str(ROOT / "configs" / "warehouse_patrol_30.yaml"))
    ap.add_argument("--timeout", type=float, default=120.0)
    ap.add_argument(
        "--shards",
        default="1",
        help="comma-separated server process counts (fleet sim-ros --shards), one run each",
    )
    ap.add_argument(
        "--domains",
        default="same",
        help="comma-separated: same (every shard on one ROS domain, one client participant) or "
        "shard (fleet sim-ros --shard-domains: a domain per shard, one client participant per "
        "domain), one run each",
    )
    ap.add_argument(
        "--hog",
        default="0",
        help="comma-separated counts of busy-loop processes run beside the row, one run each",
    )
    ap.add_argument(
        "--executor",
        default="single",
        help="comma-separated executors of the server (FLEET_ROS_EXECUTOR: single, events), one run each",
    )
    ap.add_argument(
        "--discovery-server",
        action="store_true",
        help="run FastDDS's discovery server (shipped with the ROS wheels) and point both sides at it",
    )
    ap.add_argument(
        "--client-actions",
        default="all",
        help="comma-separated: all (every backend makes its 7 action clients at start) or nav "
        "(only the two navigators; the others on first use), one run each",
    )
    ap.add_argument(
        "--goal",
        default="wait",
        choices=("wait", "here"),
        help="the goal sent to every robot: Wait(0.5 s), or NavigateToPose to where it stands",
    )
    ap.add_argument(
        "--server-timeout",
        type=float,
        default=3.0,
        help="the backends' server_timeout_s: how long a goal request may go unanswered (s)",
    )
    ap.add_argument(
        "--managers",
        default="lazy",
        help="comma-separated: lazy (each backend makes its lifecycle managers' clients on the "
        "first STARTUP, never for autostarted robots) or eager (at start, as before), one run each",
    )
    ap.add_argument(
        "--row-limit",
        type=float,
        default=None,
        help="hang guard: wall s a row may take before the bench dumps every stack, kills the "
        "server and exits 3 (default 4 x --timeout + 120)",
    )
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    # SIGTERM (e.g. `timeout`) unwinds like Ctrl-C so the server child is stopped
    signal.signal(signal.SIGTERM, lambda *_: (_ for _ in ()).throw(KeyboardInterrupt()))
    faulthandler.register(signal.SIGUSR1, all_threads=True)
    # claimed domains (fleet.ros.domains): one per shard of the largest --shards, so that
    # --domains shard (ROS_DOMAIN_ID + I - 1) meets no other run on this machine
    claim = None
    if "ROS_DOMAIN_ID" not in os.environ:
        claim = claim_domains(max(int(x) for x in args.shards.split(",")), base=190, span=40)
        os.environ["ROS_DOMAIN_ID"] = str(claim.first)
    apply_ros_env_defaults()
    rows = []
    for profile, n, hog, shards, domains, executor, actions, managers in itertools.product(
        args.profile.split(","),
        (int(x) for x in args.robots.split(",")),
        (int(x) for x in args.hog.split(",")),
        (int(x) for x in args.shards.split(",")),
        args.domains.split(","),
        args.executor.split(","),
        args.client_actions.split(","),
        args.managers.split(","),
    ):
        if shards == 1 and domains != "same" and "same" in args.domains.split(","):
            continue  # one shard has one domain: the row is already measured
        with contextlib.ExitStack() as stack:
            if args.discovery_server:
                stack.enter_context(discovery_server())
            stack.enter_context(hogs(hog))
            what = f"robots={n} hog={hog} shards={shards} domains={domains} managers={managers}"
            guard = stack.enter_context(RowGuard(args.row_limit or 4 * args.timeout + 120, what))
            row = one(
                args.config,
                n,
                profile,
                args.timeout,
                shards,
                executor,
                actions,
                args.goal,
                args.server_timeout,
                hog,
                domains,
                guard,
                managers,
            )
        row["discovery"] = "server" if args.discovery_server else "simple"
        row["profile_file"] = Path(os.environ["FASTRTPS_DEFAULT_PROFILES_FILE"]).name
        rows.append(row)
        print(json.dumps(row), flush=True)
    summarize(rows)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
