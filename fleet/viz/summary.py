"""The end-of-run summary of a fleet run, drawn with ``rich`` from the report's JSON fields
(``RunReport.to_dict()``, see ``docs/cli.md``).

Lines: ``finished`` (or ``interrupted``) with robots and simulated / wall seconds; patrols and
laps per route; picks (picking trees); goals (sent, succeeded, success rate, failures by
code, recoveries per goal, time over the straight-line / roadmap optimum); collisions, deadlocks, reassignments and throughput;
the traffic line (traffic management); the reassignments (at most
:data:`MAX_EVENTS_SHOWN`, the report has them all); then one row per robot: distance, laps,
battery, goals succeeded / sent and final state. :func:`summary_text` is the same as plain text.
"""

from __future__ import annotations

import io
from collections.abc import Mapping
from typing import Any

from rich.console import Console, Group
from rich.table import Table
from rich.text import Text

#: At most this many reassignment lines are shown.
MAX_EVENTS_SHOWN = 30


def _headline(r: Mapping[str, Any]) -> Text:
    sim, wall = float(r["sim_time_s"]), float(r["wall_time_s"])
    rate = sim / wall if wall > 0 else float("inf")
    word = "interrupted" if r.get("interrupted") else "finished"
    t = Text(word, style="bold yellow" if r.get("interrupted") else "bold green")
    t.append(f": {r['robots']} robots, {sim:.1f} s simulated in {wall:.1f} s wall ({rate:.1f}x real time)")
    return t


def _counts(r: Mapping[str, Any]) -> list[Text]:
    by_route: Mapping[str, int] = r.get("laps_by_route") or {}
    routes = " (" + ", ".join(f"{k}: {v}" for k, v in by_route.items()) + ")" if by_route else ""
    lines = [
        Text(
            f"patrols: {r['patrols_assigned']} assigned, {r['patrols_completed']} completed, "
            f"{r['laps_completed']} laps{routes}"
        )
    ]
    if r.get("picks_assigned"):
        lines.append(Text(f"picks: {r['picks_assigned']} assigned, {r['picks_completed']} completed"))
    g = r.get("goals") or {}
    if g.get("sent"):
        lines.append(_goals_line(g))
    line = Text("collisions: ")
    line.append(str(r["collisions"]), style="bold red" if r["collisions"] else "")
    line.append(f"   deadlocks: {r['deadlocks']}   reassignments: {r['reassignments']}")
    if r.get("safety_stops"):
        line.append(f"   safety stops: {r['safety_stops']}", style="bold yellow")
    line.append(f"   throughput: {float(r.get('throughput_laps_per_robot_hour', 0.0)):.1f} laps/robot-hour")
    lines.append(line)
    if r.get("malformed_messages") or r.get("rejected_messages"):
        lines.append(
            Text(
                f"dropped on the bus: {r.get('malformed_messages', 0)} malformed, "
                f"{r.get('rejected_messages', 0)} not from the live coordinator or simulator (docs/protocol.md)",
                style="yellow",
            )
        )
    if "min_battery" in r:
        low = float(r["min_battery"])
        bat = Text("battery: lowest ")
        bat.append(f"{low:.0%}", style="bold red" if low < 0.05 else "")
        bat.append(f" seen   idle: {float(r.get('idle_fraction', 0.0)):.0%} of robot time")
        lines.append(bat)
    t = r.get("traffic")
    if t is not None:
        lines.append(
            Text(
                f"traffic: mean wait {t['mean_wait_s']:.1f} s (p95 {t.get('p95_wait_s', 0.0):.1f} s, "
                f"max {t['max_wait_s']:.1f} s), "
                f"wait-for cycles {t['cycles_detected']} found / {t['cycles_resolved']} resolved, "
                f"{t['reroutes']} reroutes, {t['sidesteps']} side steps, {t['stalls']} stalls"
            )
        )
    return lines


def _goals_line(g: Mapping[str, Any]) -> Text:
    rate = g.get("success_rate")
    t = Text(f"goals: {g['sent']} sent, {g['succeeded']} succeeded")
    if rate is not None:
        t.append(f" ({rate:.1%})", style="bold red" if rate < 0.9 else "")
    failed = g.get("failed_by_code") or {}
    if failed:
        t.append(", failed: " + ", ".join(f"{k} {v}" for k, v in failed.items()), style="red")
    if g.get("canceled"):
        t.append(f", {g['canceled']} canceled")
    per_goal = g.get("recoveries_per_goal")
    if per_goal is not None:
        t.append(f"   recoveries/goal: {per_goal:.2f} (max {g['max_recoveries']})")
    straight, roadmap = g.get("time_over_straight"), g.get("time_over_roadmap")
    if straight is not None and roadmap is not None:
        t.append(f"   time/optimum: {straight:.2f}x straight line, {roadmap:.2f}x roadmap")
    return t


def _events(r: Mapping[str, Any]) -> list[Text]:
    events = list(r.get("reassignment_events") or [])
    lines = []
    for e in events[:MAX_EVENTS_SHOWN]:
        to = f"-> {e['to_robot']} at {e['t_reassigned']:.1f} s" if e.get("to_robot") else "(waiting)"
        lines.append(Text(f"  t={e['t']:.1f} s {e['route']}: {e['from_robot']} {e['reason']} {to}"))
    if len(events) > MAX_EVENTS_SHOWN:
        lines.append(
            Text(f"  ... {len(events) - MAX_EVENTS_SHOWN} more reassignments in the report", style="dim")
        )
    return lines


def _robots(r: Mapping[str, Any]) -> Table:
    t = Table(box=None, padding=(0, 2, 0, 0), pad_edge=False, header_style="bold")
    t.add_column("  robot", no_wrap=True)
    t.add_column("dist m", justify="right")
    t.add_column("laps", justify="right")
    t.add_column("battery", justify="right")
    t.add_column("goals", justify="right")
    t.add_column("state", no_wrap=True)
    for row in r.get("per_robot") or []:
        state = str(row["final_state"])
        t.add_row(
            "  " + str(row["name"]),
            f"{float(row['distance_m']):.1f}",
            str(row["laps"]),
            f"{float(row['battery_final']):.0%}",
            f"{g['succeeded']}/{g['sent']}" if (g := row.get("goals") or {}).get("sent") else "-",
            Text(state, style="bold red" if state == "dead" else ""),
        )
    return t


def summary_renderable(report: Mapping[str, Any]) -> Group:
    """The summary of ``report`` (the JSON fields of a run report) as a rich renderable."""
    return Group(_headline(report), *_counts(report), *_events(report), _robots(report))


def summary_text(report: Mapping[str, Any], width: int = 200) -> str:
    """The summary as plain text (no colors, no trailing newline); lines up to ``width``."""
    buf = io.StringIO()
    console = Console(file=buf, width=width, color_system=None, force_terminal=False, highlight=False)
    console.print(summary_renderable(report))
    return "\n".join(line.rstrip() for line in buf.getvalue().rstrip("\n").splitlines())
