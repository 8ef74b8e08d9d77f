"""Traffic management switched on in whole fleet runs (``fleet run --traffic``).

The traffic roadmap (parking spots and chargers joined as docks), the ``traffic`` config
section, grants on the bus (malformed ones counted and dropped), whole runs through the CLI
on the in-process simulator and on SUMO (no collisions, no deadlocks, every route lapped), a
low-battery robot that reaches a charger through traffic, and a fleet split over processes
(``fleet sim`` + ``fleet coordinator --traffic`` + ``fleet agent --traffic``) in which the
agent process drives by the grants it receives over Zenoh and is then killed while holding
reservations: its route is reassigned and lapped by another robot.

Real Zenoh on loopback, real py_trees, the real simulator and real SUMO.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import networkx as nx
import pytest
from fleet_procs import (
    PATROL,
    kill,
    split_fleet,
    temp_config,
    two_routes_three_robots,
    wait_for,
)
from ports import free_endpoint

from fleet.bus.keys import grant_key
from fleet.bus.session import open_session
from fleet.bus.status_bus import StatusBus
from fleet.cli.main import main
from fleet.config.loader import load_config
from fleet.errors import ConfigError, DockError
from fleet.messages import Grant
from fleet.roadmap.docks import add_docks
from fleet.traffic.policy import traffic_from_config
from fleet.types import Pose2D


def run_cli(tmp_path: Path, cfg: Path, *args: str) -> dict[str, Any]:
    report = tmp_path / "r.json"
    code = main(
        ["run", str(cfg), "--speed", "0", "--no-live", "--traffic", "--endpoint", free_endpoint(),
         "--report", str(report), *args]
    )  # fmt: skip
    assert code == 0
    return dict(json.loads(report.read_text()))


def test_traffic_management_is_on_by_default_and_no_traffic_turns_it_off(tmp_path: Path) -> None:
    """Without a flag ``fleet run`` on a shipped config manages traffic (the report has the
    traffic block and the wait figures); ``--no-traffic`` runs without it."""
    reports = {}
    for flag in ("", "--no-traffic"):
        report = tmp_path / f"r{flag}.json"
        args = ["run", str(PATROL), "--speed", "0", "--no-live", "--duration", "30"]
        args += ["--endpoint", free_endpoint(), "--report", str(report)] + ([flag] if flag else [])
        assert main(args) == 0
        reports[flag] = json.loads(report.read_text())
    assert reports[""]["traffic"] is not None and reports[""]["mean_wait_s"] is not None
    assert reports["--no-traffic"].get("traffic") is None


# ----------------------------------------------------------------------------- docks


def test_docks_join_parking_and_chargers_to_the_roadmap() -> None:
    cfg = load_config(PATROL)
    tp = traffic_from_config(cfg)
    g = tp.roadmap.graph
    clearance = tp.manager.params.clearance
    assert nx.is_connected(g)
    assert min(d["length"] for _, _, d in g.edges(data=True)) >= clearance - 1e-9
    # every parking spot, charger and start is a node; chargers are dead ends
    for p in [*cfg.parking, *(c.pose for c in cfg.chargers), *(r.start for r in cfg.robots)]:
        n = tp.roadmap.nearest_node(p.x, p.y)
        assert math.dist(tp.roadmap.pos(n), (p.x, p.y)) < 1e-6
    assert len(tp.chargers) == len(cfg.chargers) and len(tp.parking) == len(cfg.parking)
    assert all(g.degree(c) == 1 for c in tp.chargers)
    # every parking spot is a dead end off a parking lane: reached without passing another
    # spot (a robot parked in front never walls one in)
    spots = set(tp.parking)
    for p in cfg.parking:
        (nb,) = g.neighbors(tp.roadmap.nearest_node(p.x, p.y))
        assert nb not in spots and not str(nb).startswith("dock:")
    # the original roadmap is untouched
    assert cfg.roadmap.graph.number_of_nodes() < g.number_of_nodes()
    assert not any(str(n).startswith("dock:") for n in cfg.roadmap.nodes)


def test_a_dock_walled_off_from_the_roadmap_is_a_clear_error() -> None:
    cfg = load_config(PATROL)
    # a pose inside a shelf row: every connection passes through the shelf
    a1, a2 = cfg.roadmap.pos("a1_1"), cfg.roadmap.pos("a2_1")
    inside = Pose2D((a1[0] + a2[0]) / 2.0, a1[1] + 0.5)
    with pytest.raises(DockError, match="cannot be joined"):
        add_docks(cfg.roadmap.graph, [("shelf", inside)], 0.9, cfg.grid, 0.3)


@pytest.mark.parametrize(
    ("section", "field", "reason"),
    [
        ({"enabled": "yes"}, "traffic.enabled", "true or false"),
        ({"deadlock_s": -1}, "traffic.deadlock_s", "positive"),
        ({"horizon": 3}, "traffic.horizon", "unknown"),
    ],
)
def test_bad_traffic_section_names_the_field(tmp_path: Path, section: dict, field: str, reason: str) -> None:
    cfg = temp_config(tmp_path, lambda d: d.__setitem__("traffic", section))
    with pytest.raises(ConfigError) as e:
        load_config(cfg)
    assert e.value.field == field and str(cfg) in str(e.value) and reason in str(e.value)


def test_traffic_section_is_read(tmp_path: Path) -> None:
    cfg = temp_config(tmp_path, lambda d: d.__setitem__("traffic", {"enabled": True, "deadlock_s": 12}))
    c = load_config(cfg)
    assert c.traffic.enabled and c.traffic.deadlock_s == 12.0
    assert traffic_from_config(c).deadlock_s == 12.0


# ----------------------------------------------------------------------------- grants on the bus


def test_grants_round_trip_on_the_bus_and_malformed_ones_are_dropped(zenoh_endpoint: str) -> None:
    s_pub = open_session(zenoh_endpoint, "router")
    s_sub = open_session(zenoh_endpoint, "client", connect_timeout_s=10.0)
    pub, sub = StatusBus(s_pub), StatusBus(s_sub)
    got: list[Grant] = []
    probe = Grant("robot1", 0, 0, None, (), ())
    try:
        sub.subscribe_grants("robot1", got.append)

        def probe_arrived() -> bool:
            # publications are not stored: the subscription is up once a probe sent now arrives
            pub.publish_grant(probe)
            return bool(got)

        wait_for(probe_arrived, 20, "the grant subscription")
        g = Grant("robot1", 3, 7, "a", ("b", "c"), (Pose2D(1, 2, 0), Pose2D(3, 2, 0)), task_id="p-0001",
                  purpose="patrol", laps=2, seq=11)  # fmt: skip
        for bad in (
            b"{not json",
            b'{"v": 1, "robot": "robot1"}',
            json.dumps({**g.to_dict(), "robot": "robot9"}),
        ):
            s_pub.put(grant_key("robot1"), bad)
        pub.publish_grant(g)
        wait_for(lambda: g in got, 20, "the grant")
        wait_for(lambda: sub.malformed == 3, 20, "three malformed grants counted")
        assert [x for x in got if x != probe] == [g]
    finally:
        pub.close()
        sub.close()
        s_sub.close()
        s_pub.close()


# ----------------------------------------------------------------------------- whole runs


@pytest.mark.slow
def test_fleet_run_with_traffic_patrols_every_route_without_collisions_or_deadlocks(tmp_path: Path) -> None:
    r = run_cli(tmp_path, PATROL, "--duration", "240")
    assert r["robots"] == 6 and r["collisions"] == 0 and r["deadlocks"] == 0
    assert all(laps >= 1 for laps in r["laps_by_route"].values()), r["laps_by_route"]
    t = r["traffic"]
    assert t is not None and t["robots_managed"] == 6 and t["stalls"] == 0
    assert r["mean_wait_s"] == t["mean_wait_s"] >= 0.0
    assert r["throughput_laps_per_robot_hour"] == pytest.approx(
        r["laps_completed"] / (6 * 240 / 3600), rel=1e-3
    )


@pytest.mark.slow
def test_low_battery_robot_charges_through_traffic_and_its_route_is_covered(tmp_path: Path) -> None:
    def edit(doc: dict[str, Any]) -> None:
        two_routes_three_robots(doc, "robot1")
        doc["robots"][0]["battery"] = 0.5  # above its threshold at the start, below it up the aisle

    r = run_cli(tmp_path, temp_config(tmp_path, edit), "--duration", "200")
    (ev,) = [e for e in r["reassignment_events"] if e["from_robot"] == "robot1"]
    assert ev["reason"] == "charging" and ev["to_robot"] in ("robot2", "robot3")
    robot1 = next(row for row in r["per_robot"] if row["name"] == "robot1")
    assert robot1["charges"] >= 1 and robot1["battery_final"] > 0.5  # it reached a charger
    cover = next(a for a in r["assignments"] if a["task_id"] == ev["new_task_id"])
    assert cover["laps"] >= 1
    assert r["collisions"] == 0 and r["deadlocks"] == 0


@pytest.mark.sumo
@pytest.mark.slow
def test_sumo_fleet_with_traffic_completes_patrols_without_collisions(tmp_path: Path) -> None:
    r = run_cli(tmp_path, PATROL, "--backend", "sumo", "--duration", "300")
    assert r["backend"] == "sumo" and r["collisions"] == 0 and r["deadlocks"] == 0
    assert r["teleports"] == 0  # SUMO never had to move a stuck vehicle on
    assert r["patrols_completed"] >= 4 and r["laps_completed"] >= 6
    assert r["traffic"]["robots_managed"] == 6


@pytest.mark.slow
def test_agent_process_follows_grants_over_the_bus_and_its_death_releases_the_route(tmp_path: Path) -> None:
    victim = "robot2"

    def edit(doc: dict[str, Any]) -> None:
        two_routes_three_robots(doc, victim)

    cfg = temp_config(tmp_path, edit)
    speed, duration = 5.0, 200.0
    with split_fleet(tmp_path, cfg, victim, "robot1,robot3", speed, duration, "--traffic") as f:
        # the victim drives its route by the grants it receives over the bus: a first lap
        wait_for(lambda: f.bus.latest()[victim].laps >= 1, 90, f"{victim}'s first lap")
        kill(f.agent, tmp_path / "agent.log")
        r = f.result(3 * duration / speed + 60)  # hang guard: 3x the nominal run, plus start-up
    # its death is one event; a loaded machine may take work from it before, for other reasons
    # (an order it was slow to acknowledge is re-issued, "no_ack"), and then the route it held
    # at its death may be the other one
    events = [e for e in r["reassignment_events"] if e["from_robot"] == victim]
    dead = [e for e in events if e["reason"] == "dead"]
    assert len(dead) == 1, events
    ev = dead[0]
    assert ev["to_robot"] in ("robot1", "robot3"), events
    assert ev["route"] == "aisles_1_2" or len(events) > 1, events
    assert ev["t_reassigned"] - ev["t"] < 5.0
    # its laps over the bus were counted
    assert max(a["laps"] for a in r["assignments"] if a["robot"] == victim) >= 1
    # the dead robot keeps only its grant (it may still be driving its last goal): the other
    # routes go on being lapped after its death
    after = [a for a in r["assignments"] if a["robot"] != victim and (a["ended"] or duration) > ev["t"]]
    assert sum(a["laps"] for a in after) >= 2, after
    assert r["collisions"] == 0 and r["deadlocks"] == 0
