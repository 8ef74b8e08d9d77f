"""``fleet sim-ros CONFIG``: serve a :class:`~sim.simulator.Simulator` as namespaced Nav2 over
real ROS 2 (rclpy).

For every robot namespace (``/robot1`` ...) one lean node ``/robot1/nav2_sim``
(:class:`~fleet.ros.nav2_facade.RobotFacade`) exposes what a Nav2 Jazzy bringup under that
namespace exposes to clients such as ``nav2_simple_commander.BasicNavigator(namespace=
'/robot1')``: Nav2's action servers (:mod:`fleet.ros.nav2_actions`), lifecycle nodes and
managers (:mod:`fleet.ros.lifecycle`), costmap services (:mod:`fleet.ros.nav2_services`),
``tf``, ``amcl_pose``, ``odom``, ``battery_state``, ``plan`` and ``initialpose``
(:mod:`fleet.ros.nav2_facade`).

For people looking at the fleet (RViz, Foxglove), the server's ``fleet_sim`` node publishes,
in the global namespace: ``/map`` (``nav_msgs/OccupancyGrid``, transient local, once),
``/tf`` (every robot's ``map -> <robot>/odom -> <robot>/base_link``, frame-prefixed with the
robot's name) and ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray``: each robot's battery,
localization, motion and navigation checks of :mod:`fleet.diagnostics`, and each lifecycle
manager's health) at ``--diagnostics-hz``.

This module is the server process: :class:`Nav2SimServer` owns the rclpy contexts (one DDS
participant each, ``--participants``, one by default), one
single-threaded executor per context (:mod:`fleet.ros.shards`) and the simulator's time;
:func:`serve` runs it until a signal; :func:`main` is the command line. ``--shards K`` runs K
such processes instead, each serving (and simulating) a share of the robots
(:mod:`fleet.ros.shard_processes`).

Threading: with one shard everything (ROS callbacks, stepping the simulator) runs on one
thread; with more, each further shard's executor waits for work in a thread of its own, but
every callback runs holding one lock. Execute callbacks are coroutines that await the
simulator's verdict, so the simulator is never touched concurrently. Time: a timer steps the simulator so that simulated time follows wall
time times ``speed``, paced by the project's one real-time pacer, :class:`fleet.clock.Pacer`
(the only wall-clock reads, besides the wall-clock publication rates).

Command line: ``python -m fleet.ros.nav2_server CONFIG [--robots N] [--speed X] ...`` (and
``fleet sim-ros CONFIG``); see :func:`main`. It stops cleanly on SIGINT / SIGTERM.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import signal
import sys
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING

from fleet.ros.env import apply_ros_env_defaults

apply_ros_env_defaults()

from builtin_interfaces.msg import Time  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue  # noqa: E402
from nav_msgs.msg import OccupancyGrid as GridMsg  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from tf2_msgs.msg import TFMessage  # noqa: E402

from fleet.clock import Pacer, WallClock  # noqa: E402
from fleet.diagnostics import robot_diagnostics  # noqa: E402
from fleet.errors import BackendError, FleetError  # noqa: E402
from fleet.maps import FREE, OccupancyGrid  # noqa: E402
from fleet.navigation import Clock  # noqa: E402
from fleet.ros.conversions import pose2d_to_pose, seconds_to_time  # noqa: E402
from fleet.ros.executors import executor_kind  # noqa: E402
from fleet.ros.launch import ReadyInfo, write_ready  # noqa: E402
from fleet.ros.lifecycle import LIFECYCLE_NODES  # noqa: E402
from fleet.ros.nav2_facade import Profile, RobotFacade  # noqa: E402
from fleet.ros.shards import Shards  # noqa: E402
from fleet.types import Pose2D  # noqa: E402
from nodes.bt_xml import parse_file  # noqa: E402

if TYPE_CHECKING:
    from collections.abc import Sequence

    from fleet.config.model import FleetConfig
    from fleet.robots import RobotSpec
    from sim.simulator import Simulator

#: Most simulator steps one timer callback runs to catch up; beyond, the backlog is dropped
#: (the world slows down instead of spiralling when the machine cannot keep up).
MAX_CATCH_UP_STEPS = 20
#: Timer period (wall s) of the stepping timer while the world is paused (``speed`` 0).
PAUSED_TICK_S = 0.05
#: ``/map``: latched for late subscribers (RViz, Foxglove), as map_server publishes it.
MAP_QOS = QoSProfile(
    depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE
)
#: Exit status after SIGINT / SIGTERM (docs/cli.md).
EXIT_INTERRUPTED = 130

__all__ = ["LIFECYCLE_NODES", "Nav2SimServer", "Profile", "build_simulator", "main", "serve"]


class Nav2SimServer:
    """Serve ``sim`` as namespaced Nav2 for ``namespaces`` (default: every robot of the sim).

    Args:
        sim: the simulator; this server is its only user while it runs (it steps it).
        namespaces: robots to serve (each must be in the simulator, else
            :class:`~fleet.errors.BackendError`).
        speed: simulated seconds per wall second (> 0); ``0`` pauses the world (goals are
            accepted, nothing moves).
        feedback_hz, odom_hz, amcl_hz: wall-clock publication rates (``0`` disables).
        profile: :class:`~fleet.ros.nav2_facade.Profile` (or its name): ``full`` serves every
            Nav2 interface, ``lean`` the seven navigation actions, lifecycle and the topics.
        diagnostics_hz: wall-clock rate of ``/diagnostics`` (``0`` disables).
        autostart: bring every robot's lifecycle nodes up at once (Nav2's ``autostart``);
            otherwise they wait, unconfigured, for ``manage_nodes`` STARTUP.
        context: an initialized rclpy ``Context``; by default the server creates and owns one.
        domain_id: ROS domain of the context it creates (default: ``ROS_DOMAIN_ID``).
        wall: the wall clock the simulator is paced against (default
            :class:`~fleet.clock.WallClock`; tests pass their own).
        nav_to_pose_xml, nav_through_poses_xml: the navigator trees of goals with an empty
            ``behavior_tree`` (default: the project's ``nodes/trees/navigate_to_pose.xml`` /
            ``navigate_through_poses.xml``).
        participants: spread the robots' nodes over this many rclpy contexts, i.e. DDS
            participants (robot ``k`` in participant ``k % participants``), each with its own executor
            and thread, callbacks serialized by one lock (:mod:`fleet.ros.shards`: the
            simulator stays one world, touched by one callback at a time). Needs ``context``
            unset when above 1.
        world_node: name of the node publishing ``/map``, ``/tf`` and ``/diagnostics``.

    Call :meth:`spin` (blocks until :meth:`request_stop`, e.g. from a signal handler) or
    :meth:`spin_once` in your own loop, then :meth:`close`.
    """

    def __init__(
        self,
        sim: Simulator,
        namespaces: list[str] | None = None,
        *,
        speed: float = 1.0,
        feedback_hz: float = 10.0,
        odom_hz: float = 10.0,
        amcl_hz: float = 1.0,
        profile: Profile | str = Profile.FULL,
        diagnostics_hz: float = 1.0,
        autostart: bool = True,
        context: Context | None = None,
        domain_id: int | None = None,
        wall: Clock | None = None,
        nav_to_pose_xml: str | None = None,
        nav_through_poses_xml: str | None = None,
        participants: int = 1,
        world_node: str = "fleet_sim",
    ) -> None:
        profile = Profile.parse(profile)
        if not speed >= 0 or speed == float("inf"):
            raise BackendError(f"speed must be a finite number >= 0, got {speed}")
        self.shards = Shards(participants, domain_id, context)  # the DDS participants (fleet.ros.shards)
        self.sim = sim
        self.speed = float(speed)
        self.wall = wall if wall is not None else WallClock()
        self.pacer = Pacer(sim.clock, self.speed, wall=self.wall)
        feedback_period = 1.0 / feedback_hz if feedback_hz > 0 else None
        contexts = self.contexts = self.shards.contexts  # the world node's is the first
        self.executors = self.shards.executors
        self.context, self.executor = contexts[0], self.executors[0]
        self._stop = False
        #: Why the server stopped: ``"signal"``, ``"duration"`` (set by :func:`serve`), or ``""``.
        self.stopped_by = ""
        #: Simulated time the world does not step beyond (``serve``'s ``duration_s``).
        self.end_time: float | None = None
        t_create = self.wall.now()
        self.world = Node(
            world_node, context=self.context, start_parameter_services=False, enable_rosout=False
        )
        self.robots: dict[str, RobotFacade] = {}
        for k, ns in enumerate(namespaces if namespaces is not None else list(sim.namespaces)):
            sim.robot_state(ns)  # raises BackendError for an unknown robot
            self.robots[ns] = RobotFacade(
                sim,
                ns,
                contexts[k % participants],
                profile,
                stamp=self.stamp,
                feedback_period=feedback_period,
                wall=self.wall,
                autostart=autostart,
            )
        for r in self.robots.values():
            r.actions.set_default_trees(nav_to_pose_xml, nav_through_poses_xml)
        #: Wall seconds it took to create every robot's interfaces.
        self.create_time_s = self.wall.now() - t_create
        self.executor.add_node(self.world)
        for k, r in enumerate(self.robots.values()):
            for node in r.nodes:
                self.executors[k % participants].add_node(node)
        self.tf_pub = self.world.create_publisher(TFMessage, "/tf", 100)
        self.map_pub = self.world.create_publisher(GridMsg, "/map", MAP_QOS)
        self.diag_pub = self.world.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.map_pub.publish(map_msg(sim.grid, self.stamp()))
        step = sim.params.step_s
        self.world.create_timer(
            max(step / self.speed, 0.01) if self.speed > 0 else PAUSED_TICK_S, self.step_to_wall_time
        )
        if odom_hz > 0:
            self.world.create_timer(1.0 / odom_hz, self._publish_odom)
        if amcl_hz > 0:
            self.world.create_timer(1.0 / amcl_hz, self._publish_amcl)
        if diagnostics_hz > 0:
            self.world.create_timer(1.0 / diagnostics_hz, self.publish_diagnostics)
        self._publish_amcl()
        self.pacer.start()
        self.shards.start()

    # -- time -----------------------------------------------------------------------------

    def stamp(self) -> Time:
        """The header stamp of now: simulated time."""
        return seconds_to_time(self.sim.clock.now())

    def step_to_wall_time(self) -> None:
        """Step the simulator while it is at least one step behind ``speed`` times the wall
        time passed (at most :data:`MAX_CATCH_UP_STEPS` steps; a larger backlog is dropped),
        then resolve finished goals and publish due feedback. The server's timer calls it."""
        if self.speed > 0:
            step = self.sim.params.step_s
            n = 0
            # simulated seconds owed: the pacer's lag times the speed
            while -self.pacer.ahead() * self.speed >= step - 1e-9:
                if self.end_time is not None and self.sim.clock.now() >= self.end_time - 1e-9:
                    break  # the run's --duration is reached: the world stops there
                if n == MAX_CATCH_UP_STEPS:
                    self.pacer.start()  # cannot keep up: drop the backlog rather than spiral
                    break
                self.sim.step()
                n += 1
        wall = self.wall.now()
        for r in self.robots.values():
            r.actions.poll_all(wall)

    def _publish_odom(self) -> None:
        """Every robot's ``odom``, ``tf``, ``battery_state`` and ``plan``, and the fleet's ``/tf``."""
        stamp = self.stamp()
        fleet_tf = []
        for r in self.robots.values():
            r.publish_odom(stamp)
            fleet_tf.extend(r.transforms(stamp, prefix=f"{r.name}/"))
        self.tf_pub.publish(TFMessage(transforms=fleet_tf))

    def publish_diagnostics(self) -> None:
        """``/diagnostics``: every robot's checks (:func:`fleet.diagnostics.robot_diagnostics`,
        named ``<robot>: <check>``, hardware id the robot's name) and its lifecycle managers'
        health (``<robot>: <manager>``)."""
        arr = DiagnosticArray()
        arr.header.stamp = self.stamp()
        out = []
        for r in self.robots.values():
            for d in robot_diagnostics(self.sim.robot_state(r.ns)):
                st = DiagnosticStatus(
                    level=bytes([int(d.level)]),
                    name=f"{r.name}: {d.name}",
                    message=d.message,
                    hardware_id=r.name,
                )
                st.values = [KeyValue(key=k, value=v) for k, v in d.values]
                out.append(st)
            for manager, level, message in r.lifecycle.health():
                out.append(
                    DiagnosticStatus(
                        level=bytes([level]), name=f"{r.name}: {manager}", message=message, hardware_id=r.name
                    )
                )
        arr.status = out
        self.diag_pub.publish(arr)

    def _publish_amcl(self) -> None:
        for r in self.robots.values():
            r.publish_pose()

    # -- running --------------------------------------------------------------------------

    def spin_once(self, timeout_s: float = 0.1) -> None:
        """Run at most one ready callback of the first shard (the world node's, and its
        robots'), waiting up to ``timeout_s`` wall seconds for one; the other shards spin in
        threads of their own (callbacks never run concurrently)."""
        self.shards.spin_once(timeout_s)

    def request_stop(self) -> None:
        """Make :meth:`spin` return (safe from a signal handler or another thread)."""
        self._stop = True

    @property
    def running(self) -> bool:
        """False once :meth:`request_stop` was called or the context was shut down."""
        return not self._stop and self.shards.ok()

    def spin(self) -> None:
        """Serve until :meth:`request_stop` (or the context shuts down)."""
        while self.running:
            self.spin_once(0.1)

    def close(self) -> None:
        """Abort nothing, destroy every node, shut the context down (if the server owns it)."""
        self.shards.stop()
        for r in self.robots.values():
            r.destroy()
        self.world.destroy_node()
        self.shards.close()

    @property
    def served(self) -> list[str]:
        """The namespaces served."""
        return list(self.robots)


def build_simulator(config_path: str, robots: int | None = None) -> Simulator:
    """Load a fleet config and make a simulator with its robots (``robots`` overrides the count)."""
    from fleet.config.loader import load_config

    return simulator_for(load_config(config_path, robots=robots))


def simulator_for(cfg: FleetConfig, robots: Sequence[RobotSpec] | None = None) -> Simulator:
    """A simulator with the robots of the loaded config ``cfg`` (or only ``robots`` of them)."""
    from fleet.clock import SimClock
    from sim.simulator import Simulator

    sim = Simulator(cfg.grid, cfg.sim, SimClock())
    for spec in cfg.robots if robots is None else robots:
        sim.add_robot(spec)
    return sim


def map_msg(grid: OccupancyGrid, stamp: Time) -> GridMsg:
    """The ``nav_msgs/OccupancyGrid`` (frame ``map``) of the static map: free 0, else 100."""
    m = GridMsg()
    m.header.frame_id = "map"
    m.header.stamp = stamp
    m.info.map_load_time = stamp
    m.info.resolution = float(grid.resolution)
    m.info.width = grid.width
    m.info.height = grid.height
    m.info.origin = pose2d_to_pose(Pose2D(grid.origin_x, grid.origin_y, 0.0))
    m.data = ((grid.cells != FREE).astype("int8") * 100).ravel().tolist()
    return m


# long: one add_argument per option of the command
def build_parser() -> argparse.ArgumentParser:
    """The ``fleet sim-ros`` argument parser."""
    ap = argparse.ArgumentParser(
        prog="fleet sim-ros",
        description=(
            "Serve the simulated fleet of CONFIG as namespaced Nav2 over ROS 2: for every robot "
            "/NAME, the Nav2 action servers (navigate_to_pose, navigate_through_poses, "
            "follow_waypoints, spin, backup, ...), lifecycle nodes and managers, tf, amcl_pose, "
            "odom, battery_state, plan and the costmap services; for the whole fleet /map, /tf "
            "and /diagnostics (open RViz or Foxglove with fixed frame 'map'). "
            "nav2_simple_commander's BasicNavigator(namespace='/robot1') works against it. "
            "Stop with Ctrl-C (exit 130)."
        ),
        epilog="examples:\n"
        "  fleet sim-ros configs/warehouse_patrol.yaml --speed 5\n"
        "  fleet sim-ros configs/warehouse_patrol.yaml --duration 300 --plot out/truth.png\n"
        "  fleet sim-ros configs/warehouse_patrol.yaml --no-autostart   # bring Nav2 up with manage_nodes\n",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("config", help="fleet config YAML (see docs/config.md)")
    ap.add_argument("--robots", type=int, default=None, help="serve N robots instead of the config's list")
    ap.add_argument(
        "--speed", type=float, default=1.0, help="simulated seconds per wall second (default 1; 0 pauses)"
    )
    ap.add_argument(
        "--profile",
        choices=[p.value for p in Profile],
        default=Profile.FULL.value,
        help="which Nav2 interfaces to serve",
    )
    ap.add_argument("--feedback-hz", type=float, default=10.0, help="action feedback rate (wall Hz)")
    ap.add_argument("--odom-hz", type=float, default=10.0, help="odom and tf rate (wall Hz, 0 = off)")
    ap.add_argument("--amcl-hz", type=float, default=1.0, help="amcl_pose rate (wall Hz, 0 = off)")
    ap.add_argument("--diagnostics-hz", type=float, default=1.0, help="/diagnostics rate (wall Hz, 0 = off)")
    ap.add_argument(
        "--no-autostart",
        action="store_true",
        help="leave the Nav2 lifecycle nodes unconfigured until a manage_nodes STARTUP",
    )
    ap.add_argument("--domain-id", type=int, default=None, help="ROS_DOMAIN_ID (default: the environment's)")
    ap.add_argument(
        "--shards",
        type=int,
        default=1,
        help="serve the robots from K processes, each simulating its share of them (robot i in "
        "shard (i-1) %% K; robots of different shards do not see each other: see docs/ros.md, "
        "Scale); default 1",
    )
    ap.add_argument(
        "--participants",
        type=int,
        default=1,
        help="DDS participants (rclpy contexts) one process spreads its robots' nodes over "
        "(default 1; more did not make discovery faster here: docs/ros.md, Scale)",
    )
    shard_domains_help = "with --shards: shard I on ROS_DOMAIN_ID + I - 1 (docs/ros.md, Shards)"
    ap.add_argument("--shard-domains", action="store_true", help=shard_domains_help)
    ap.add_argument("--shard-of", default=None, help=argparse.SUPPRESS)  # I/K: one shard's process
    ap.add_argument("--ready-file", default=None, help="write a JSON line here once every server exists")
    ap.add_argument("--duration", type=float, default=None, help="stop after this many simulated seconds")
    ap.add_argument(
        "--nav-to-pose-xml",
        default=None,
        metavar="FILE",
        help="navigator tree (BehaviorTree.CPP XML) of NavigateToPose goals with an empty behavior_tree "
        "(default: the project's nodes/trees/navigate_to_pose.xml; Nav2's own trees load too)",
    )
    ap.add_argument(
        "--nav-through-poses-xml",
        default=None,
        metavar="FILE",
        help="navigator tree of NavigateThroughPoses goals with an empty behavior_tree "
        "(default: the project's nodes/trees/navigate_through_poses.xml)",
    )
    ap.add_argument("--plot", default=None, help="write a PNG of the robots' true trajectories at the end")
    ap.add_argument(
        "--truth",
        default=None,
        help="write the ground truth at the end as JSON: each robot's trajectory (t, x, y), "
        "odometer (m) and final pose",
    )
    return ap


def main(argv: list[str] | None = None) -> int:
    """``fleet sim-ros CONFIG``: serve the config's simulated robots as namespaced Nav2.
    Returns the exit status: 0 after ``--duration``, 130 after Ctrl-C / SIGTERM, 2 for a bad
    config or argument."""
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser().parse_args(argv)
    for opt in ("shards", "participants"):
        if getattr(args, opt) < 1:
            print(f"error: --{opt} must be at least 1, got {getattr(args, opt)}", file=sys.stderr)
            return 2
    if args.duration is not None and not args.duration > 0:
        print(
            f"error: --duration must be a positive number of simulated seconds, got {args.duration}",
            file=sys.stderr,
        )
        return 2
    if args.domain_id is not None:
        apply_ros_env_defaults(args.domain_id)
    try:
        executor_kind()
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    try:
        from fleet.config.loader import load_config
        from fleet.ros.shard_processes import follow_parent, run_shards, shard_of

        cfg = load_config(args.config, robots=args.robots)
        index, count = shard_of(args.shard_of) if args.shard_of else (0, 1)
        parent = args.shards > 1 and args.shard_of is None  # its shards simulate, it does not
        sim = simulator_for(cfg, [] if parent else cfg.robots[index::count])
        for tree in (args.nav_to_pose_xml, args.nav_through_poses_xml):
            if tree is not None:
                parse_file(tree)  # a default tree that cannot load is an error at start, as in Nav2
    except (FleetError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if parent:
        return run_shards(
            cfg, argv, args.shards, ready_file=args.ready_file, truth=args.truth, plot=args.plot,
            domains=args.shard_domains,
        )  # fmt: skip
    if args.shard_of:
        follow_parent()
    code = serve(
        sim,
        speed=args.speed,
        feedback_hz=args.feedback_hz,
        odom_hz=args.odom_hz,
        amcl_hz=args.amcl_hz,
        diagnostics_hz=args.diagnostics_hz,
        autostart=not args.no_autostart,
        profile=args.profile,
        domain_id=args.domain_id,
        ready_file=args.ready_file,
        duration_s=args.duration,
        nav_to_pose_xml=args.nav_to_pose_xml,
        nav_through_poses_xml=args.nav_through_poses_xml,
        participants=args.participants,
        label=f"sim-ros shard {index + 1}/{count}" if args.shard_of else "sim-ros",
        world_node="fleet_sim" if index == 0 else f"fleet_sim_shard{index + 1}",
    )
    if args.truth:
        write_truth(sim, args.truth)
        print(f"[sim-ros] ground truth: {args.truth}", flush=True)
    if args.plot:
        from fleet.viz.plot import plot_run

        trajectories = {r.name: sim.trajectory(r.namespace) for r in cfg.robots}
        plot_run(cfg, trajectories, args.plot, title=f"{cfg.name} (fleet sim-ros, true trajectories)")
        print(f"[sim-ros] plot: {args.plot}", flush=True)
    return code


def write_truth(sim: Simulator, path: str) -> None:
    """The simulator's ground truth as JSON: ``{"t": now, "robots": {ns: {"trajectory": [[t, x,
    y], ...], "distance_m": odometer, "pose": [x, y, theta]}}}`` (``map`` frame, m, s)."""
    robots = {}
    for ns in sim.namespaces:
        st = sim.localization_state(ns)
        robots[ns] = {
            "trajectory": [list(p) for p in sim.trajectory(ns)],
            "distance_m": sim.robot_state(ns).distance_m,
            "pose": list(sim.true_pose(ns).as_tuple()),
            "estimate_error_m": st.error_m,
        }
    Path(path).write_text(json.dumps({"t": sim.clock.now(), "robots": robots}))


def serve(
    sim: Simulator,
    *,
    ready_file: str | None = None,
    duration_s: float | None = None,
    speed: float = 1.0,
    feedback_hz: float = 10.0,
    odom_hz: float = 10.0,
    amcl_hz: float = 1.0,
    diagnostics_hz: float = 1.0,
    autostart: bool = True,
    profile: Profile | str = Profile.FULL,
    domain_id: int | None = None,
    nav_to_pose_xml: str | None = None,
    nav_through_poses_xml: str | None = None,
    participants: int = 1,
    label: str = "sim-ros",
    world_node: str = "fleet_sim",
) -> int:
    """Serve ``sim`` (the other arguments are :class:`Nav2SimServer`'s; ``label`` starts the
    printed lines) until SIGINT/SIGTERM or ``duration_s`` simulated seconds have passed. Writes
    ``ready_file`` (:class:`~fleet.ros.launch.ReadyInfo`) once every server exists. Returns the
    exit status: 0 after the duration, :data:`EXIT_INTERRUPTED` after a signal."""
    wall = WallClock()
    t0 = wall.now()
    server = Nav2SimServer(
        sim,
        speed=speed,
        feedback_hz=feedback_hz,
        odom_hz=odom_hz,
        amcl_hz=amcl_hz,
        diagnostics_hz=diagnostics_hz,
        autostart=autostart,
        profile=profile,
        domain_id=domain_id,
        nav_to_pose_xml=nav_to_pose_xml,
        nav_through_poses_xml=nav_through_poses_xml,
        participants=participants,
        world_node=world_node,
    )
    gc.freeze()  # the robots' ROS objects live as long as this process: the collector skips them

    def _stop(_sig: int, _frame: FrameType | None) -> None:
        server.stopped_by = "signal"
        server.request_stop()

    signal.signal(signal.SIGINT, _stop)
    signal.signal(signal.SIGTERM, _stop)
    info: ReadyInfo = {
        "pid": os.getpid(),
        "robots": server.served,
        "create_s": round(wall.now() - t0, 3),
        "domain_id": os.environ.get("ROS_DOMAIN_ID", "0"),
        "shards": 1,
        "participants": len(server.contexts),
    }
    print(
        f"[{label}] serving {len(server.served)} robots as namespaced Nav2 over {info['participants']} DDS "
        f"participant(s) (created in {info['create_s']} s, "
        f"ROS_DOMAIN_ID={info['domain_id']}); Ctrl-C stops",
        flush=True,
    )
    if ready_file:
        write_ready(ready_file, info)
    sim_t0 = sim.clock.now()
    if duration_s is not None:
        server.end_time = sim_t0 + duration_s
    try:
        while server.running:
            if duration_s is not None and sim.clock.now() - sim_t0 >= duration_s - 1e-9:
                server.stopped_by = "duration"
                break
            server.spin_once(0.1)
    finally:
        server.close()
    t = sim.clock.now() - sim_t0
    print(f"[{label}] stopped ({server.stopped_by or 'shut down'}) after {t:.1f} s simulated", flush=True)
    return EXIT_INTERRUPTED if server.stopped_by == "signal" else 0


if __name__ == "__main__":
    sys.exit(main())
