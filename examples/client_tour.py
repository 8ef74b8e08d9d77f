"""A tour of ``FleetClient`` against a running fleet (docs/service.md).

Start a fleet with its API, then run this in a second terminal::

    fleet run configs/warehouse_patrol.yaml --tree picking --api 127.0.0.1:8080
    python examples/client_tour.py --api 127.0.0.1:8080

It sends a robot to a roadmap node and waits for it, runs a two-lap patrol, starts an endless
patrol and cancels it, pauses and resumes the fleet, e-stops it, and releases it. Exits 0 when
every step went as expected.
"""

from __future__ import annotations

import argparse
import sys
import time

from fleet.client import FleetClient


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--api", default="127.0.0.1:8080", help="the fleet's API (HOST:PORT)")
    p.add_argument("--timeout", type=float, default=300.0, help="wall seconds to wait for each task")
    args = p.parse_args()
    fleet = FleetClient(args.api, user="client_tour")

    robots = fleet.robots()
    print(f"{len(robots)} robots:", ", ".join(f"{r['name']} {r['state']} {r['battery']:.0%}" for r in robots))

    go = fleet.go_to("a3_n")
    print(f"{go.id}: go_to a3_n ->", go.wait(args.timeout), "by", go.robot)

    patrol = fleet.patrol(["a1_s", "a1_n"], laps=2)
    print(f"{patrol.id}: 2-lap patrol ->", patrol.wait(args.timeout), "laps", patrol.data["laps"])

    endless = fleet.patrol(["a6_s", "a6_n"])
    deadline = time.monotonic() + args.timeout
    while endless.refresh().state != "active" and not endless.done and time.monotonic() < deadline:
        time.sleep(0.2)
    print(f"{endless.id}: endless patrol {endless.state} on {endless.robot}; canceling ->", endless.cancel())
    endless.wait(args.timeout)

    print("pause ->", fleet.pause("tour")["state"], "; resume ->", fleet.resume("tour")["state"])
    print("estop ->", fleet.estop("tour")["state"], "; release ->", fleet.release("tour")["state"])
    print("resume ->", fleet.resume("tour")["state"])

    ok = go.state == "completed" and patrol.state == "completed" and endless.state == "canceled"
    print("tour", "ok" if ok else "FAILED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
