"""``fleet task submit|list|show|cancel`` and ``fleet pause|resume|estop|release``: a running
fleet's task service over its HTTP API (``--api HOST:PORT``, default ``$FLEET_API`` or
``127.0.0.1:8080``; see ``docs/service.md``).

Exit codes: 0 ok; 1 ``submit --wait`` ended in ``failed`` or ``canceled`` (or timed out);
2 bad input or an error answer (one line ``error: <field>: <reason> (HTTP <status>)``) or the
fleet cannot be reached. ``--json`` prints the API's JSON answer instead of text.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

from fleet.cli.common import EXIT_ERROR, EXIT_OK, SubParsers, add_command
from fleet.client import FleetClient
from fleet.errors import ApiError

#: Where the API is unless ``--api`` or ``$FLEET_API`` say otherwise.
DEFAULT_API = "127.0.0.1:8080"

TASK_EPILOG = """\
examples:
  fleet task submit go_to --target a3_n --wait
  fleet task submit go_to --target 12.0,5.0,1.57          (a pose: x,y[,theta], map frame)
  fleet task submit patrol --waypoints a1_s,a1_n --laps 2 --priority 10
  fleet task submit patrol --route aisles_1_2              (a config route, until canceled)
  fleet task submit pick --pickup pick_a2_1_w --dropoff drop1 --robot robot3
  fleet task submit inspection --waypoints a5_s,a5_n --action capture
  fleet task submit --spec '{"kind": "park"}'
  fleet task list --state active          fleet task show t-0007      fleet task cancel t-0007
"""


def add_api(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--api",
        default=os.environ.get("FLEET_API", DEFAULT_API),
        metavar="HOST:PORT",
        help=f"the fleet's API (fleet run --api ...; default $FLEET_API or {DEFAULT_API})",
    )
    p.add_argument("--json", action="store_true", help="print the API's JSON answer")
    p.add_argument("--user", default=os.environ.get("USER", "cli"), help="who asks (X-Fleet-User)")
    p.add_argument(
        "--secure",
        type=Path,
        metavar="DIR",
        default=os.environ.get("FLEET_SECURE") or None,
        help="key directory of a secured fleet (fleet keys init): send its API token "
        "(DIR/api.token) with mutating calls (default $FLEET_SECURE)",
    )


def client_of(args: argparse.Namespace) -> FleetClient:
    """The API client of a task command (with the token of ``--secure DIR``)."""
    from fleet.bus.keyring import Keyring

    token = Keyring(Path(args.secure)).api_token() if args.secure else None
    return FleetClient(args.api, user=args.user, token=token)


def add_parser(sub: SubParsers) -> argparse.ArgumentParser:
    p = add_command(
        sub,
        "task",
        handle_task,
        help="submit, list, show or cancel tasks of a running fleet (its --api)",
        description="Tasks of a running fleet, through its HTTP API (docs/service.md).",
        epilog=TASK_EPILOG,
    )
    tsub = p.add_subparsers(dest="task_command", metavar="ACTION", required=True)
    s = tsub.add_parser("submit", help="submit a task", formatter_class=argparse.RawDescriptionHelpFormatter)
    s.add_argument("kind", nargs="?", help="go_to, patrol, pick, inspection, charge or park")
    s.add_argument("--spec", metavar="JSON", help="the whole task as JSON (other options add to it)")
    s.add_argument("--target", help="go_to/park: station, roadmap node, or x,y[,theta]")
    s.add_argument("--waypoints", help="patrol/inspection: comma-separated names or x;y[;theta] poses")
    s.add_argument("--route", help="patrol: a route of the fleet config")
    s.add_argument("--laps", type=int, help="patrol: laps (default: until canceled)")
    s.add_argument("--pickup", help="pick: where to pick up")
    s.add_argument("--dropoff", help="pick: where to drop off")
    s.add_argument("--dwell", type=float, dest="dwell_s", help="pick: seconds at the pickup")
    s.add_argument("--action", help="inspection: wait, spin, capture or capture:<name>")
    s.add_argument("--duration", type=float, dest="duration_s", help="inspection: seconds of a wait")
    s.add_argument("--priority", type=int, help="higher first (-1000..1000)")
    s.add_argument("--robot", help="the one robot allowed to take it")
    s.add_argument("--name", help="a label")
    s.add_argument("--wait", action="store_true", help="wait until the task ends (exit 1 unless completed)")
    s.add_argument("--timeout", type=float, default=None, help="with --wait: give up after so many seconds")
    add_api(s)
    ls = tsub.add_parser("list", help="list tasks")
    ls.add_argument("--state", help="only tasks in this state")
    add_api(ls)
    for name, what in (("show", "one task and its latest events"), ("cancel", "cancel a task")):
        q = tsub.add_parser(name, help=what)
        q.add_argument("id", help="the task id, e.g. t-0007")
        add_api(q)
    for action, what in (
        ("pause", "robots stop where they are and keep their tasks"),
        ("resume", "robots carry on (refused while the e-stop is latched)"),
        ("estop", "emergency stop: every robot stops at once, latched until release"),
        ("release", "unlatch the e-stop; the fleet stays paused until resume"),
    ):
        c = add_command(
            sub, action, handle_command, help=f"{what} (a running fleet's --api)", description=what
        )
        c.add_argument("--reason", default="", help="why (kept in the report and the API)")
        add_api(c)
        c.set_defaults(action=action)
    return p


def target(text: str) -> Any:
    """``a3_n`` stays a name; ``12,5`` or ``12,5,1.57`` (or with ``;``) becomes a pose list."""
    parts = text.replace(";", ",").split(",")
    if len(parts) in (2, 3):
        try:
            return [float(x) for x in parts]
        except ValueError:
            pass
    return text


def build_spec(args: argparse.Namespace) -> dict[str, Any]:
    spec: dict[str, Any] = {}
    if args.spec:
        try:
            spec = json.loads(args.spec)
        except ValueError as e:
            raise ApiError(0, f"--spec is not valid JSON: {e}") from None
        if not isinstance(spec, dict):
            raise ApiError(0, "--spec must be a JSON object")
    if args.kind:
        spec["kind"] = args.kind
    for key in ("route", "laps", "dwell_s", "action", "duration_s", "priority", "robot", "name"):
        v = getattr(args, key)
        if v is not None:
            spec[key] = v
    for key in ("target", "pickup", "dropoff"):
        v = getattr(args, key)
        if v is not None:
            spec[key] = target(v)
    if args.waypoints is not None:
        spec["waypoints"] = [target(w) for w in args.waypoints.split(",")]
    return spec


def line(t: dict[str, Any]) -> str:
    robot = t.get("robot") or "-"
    extra = f"  laps {t['laps']}" if t.get("kind") == "patrol" else ""
    msg = f"  {t['message']}" if t.get("message") else ""
    return f"{t['id']:<8} {t['kind']:<10} {t['state']:<9} {robot:<10}{extra}{msg}"


def _out(args: argparse.Namespace, data: Any, text: str) -> None:
    print(json.dumps(data, indent=2) if args.json else text)


def handle_task(args: argparse.Namespace) -> int:
    client = client_of(args)
    try:
        if args.task_command == "submit":
            h = client.submit(build_spec(args))
            if not args.json:
                print(f"submitted {h.id} ({h.data['kind']})")
            if args.wait:
                h.wait(args.timeout)
            _out(args, h.data, line(h.data) if args.wait else "")
            return EXIT_OK if not args.wait or h.state == "completed" else 1
        if args.task_command == "list":
            ts = client.tasks(args.state)
            _out(args, ts, "\n".join(line(t) for t in ts) or "no tasks")
        elif args.task_command == "show":
            t = client.task(args.id)
            evs = "\n".join(
                f"  {e['at']}  t={e['t']:.1f}  {e['event']:<9} {e['text']}" for e in t.get("events", [])
            )
            _out(args, t, f"{line(t)}\n{evs}")
        else:
            h = client.handle(args.id)
            h.cancel()
            _out(args, h.data, line(h.data))
    except ApiError as e:
        print(f"error: {e}", file=sys.stderr)
        return EXIT_ERROR
    return EXIT_OK


def handle_command(args: argparse.Namespace) -> int:
    client = client_of(args)
    try:
        ctl = client.command(args.action, args.reason)
    except ApiError as e:
        print(f"error: {e}", file=sys.stderr)
        return EXIT_ERROR
    _out(args, ctl, f"fleet {ctl['state']} ({ctl['action']} by {ctl['by']} at {ctl['at']})")
    return EXIT_OK
