"""The dashboard in a real headless Chromium (Debian's ``chromium`` + ``chromedriver`` through
selenium) against a real ``fleet run ... --traffic --api 127.0.0.1:PORT`` on the simulator:
the page draws one marker per robot and they move, reserved segments arrive, a task submitted
through the form ends ``completed``, a bad one is refused naming the field, the E-STOP
button stops every robot until Release and Resume, and the form builds patrols and picks
(stations picked by clicking the map) that the task table's buttons cancel; after a
``kill -9`` and restart of the fleet on the same port and ``--state``, the page reconnects.

Real Zenoh on loopback, real py_trees, the real simulator and API. Waits are on conditions
with deadlines (at least 3x what a loaded 2-core machine needs), never fixed sleeps; the fleet
process is terminated, then killed, at the end. Without the browser the tests are skipped and
say why (``make setup-browser`` installs it).
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from ports import free_endpoint, pick_free_port

from fleet.dashboard.browser import (
    BrowserUnavailable,
    counts,
    find_programs,
    headless_chromium,
    stats,
    wait_until,
)

ROOT = Path(__file__).resolve().parents[3]
PATROL = ROOT / "configs" / "warehouse_patrol.yaml"
ROBOTS = 6
#: Fleet time runs this many times faster than wall time in these tests.
SPEED = 4

pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]


@dataclass
class Fleet:
    url: str
    proc: subprocess.Popen[bytes]
    log: Path

    def get(self, path: str) -> Any:
        with urllib.request.urlopen(self.url + path, timeout=10) as r:
            return json.loads(r.read())

    def post(self, path: str) -> Any:
        req = urllib.request.Request(self.url + path, data=b"{}", method="POST")
        req.add_header("Content-Type", "application/json")
        with urllib.request.urlopen(req, timeout=10) as r:
            return json.loads(r.read())

    def alive(self) -> bool:
        if self.proc.poll() is not None:
            raise AssertionError(
                f"fleet run exited with {self.proc.returncode}:\n{self.log.read_text()[-4000:]}"
            )
        return True


@pytest.fixture(scope="module")
def browser_ok() -> None:
    try:
        find_programs()
    except BrowserUnavailable as e:
        pytest.skip(str(e))


def start_fleet(tmp: Path, port: int, log_name: str = "fleet.log") -> Fleet:
    """``fleet run`` of the patrol config with traffic management and the API on ``port``,
    its task book in ``tmp/state``; returns once the API lists every robot with a pose."""
    log = tmp / log_name
    args = [
        sys.executable, "-m", "fleet.cli", "run", str(PATROL), "--traffic", "--no-live",
        "--speed", str(SPEED), "--duration", "7200", "--endpoint", free_endpoint(),
        "--api", f"127.0.0.1:{port}", "--state", str(tmp / "state"),
    ]  # fmt: skip
    with open(log, "wb") as out:
        proc = subprocess.Popen(args, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT)
    f = Fleet(f"http://127.0.0.1:{port}", proc, log)
    try:
        wait_until(
            lambda: f.alive() and sum(r["pose"] is not None for r in f.get("/api/robots")) == ROBOTS,
            120,
            "the API to list every robot with a pose",
            step=0.2,
        )
    except BaseException:
        stop_fleet(f)
        raise
    return f


def stop_fleet(f: Fleet) -> None:
    f.proc.terminate()
    try:
        f.proc.wait(15)
    except subprocess.TimeoutExpired:
        f.proc.kill()
        f.proc.wait(15)


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory, browser_ok: None) -> Iterator[Fleet]:
    f = start_fleet(tmp_path_factory.mktemp("dashboard"), pick_free_port())
    try:
        yield f
    finally:
        stop_fleet(f)


@pytest.fixture(scope="module")
def page(fleet: Fleet) -> Iterator[Any]:
    with headless_chromium() as driver:
        driver.get(fleet.url + "/")
        wait_until(lambda: counts(driver).get("markers") == ROBOTS, 90, f"{ROBOTS} robot markers")
        wait_until(
            lambda: len(driver.find_elements("css selector", "#robots tbody tr[data-robot]")) == ROBOTS,
            30,
            "the robots table",
        )
        yield driver


def markers(driver: Any) -> dict[str, dict[str, Any]]:
    return {m["name"]: m for m in driver.execute_script("return window.fleetDashboard.markers()")}


def robot_messages(driver: Any) -> int:
    return int(stats(driver)["robotMessages"])


def test_page_draws_one_marker_per_robot_and_they_move(page: Any, fleet: Fleet) -> None:
    api = {r["name"] for r in fleet.get("/api/robots")}
    assert len(api) == ROBOTS
    # the count is in the DOM, on the canvas, and in the markers the page drew
    assert page.find_element("id", "robot-count").get_attribute("data-count") == str(ROBOTS)
    assert page.find_element("id", "map").get_attribute("data-markers") == str(ROBOTS)
    first = markers(page)
    assert set(first) == api
    assert page.find_element("id", "fleet-name").text == "warehouse_patrol"
    assert len(page.find_elements("css selector", "#robots tbody tr[data-robot]")) == ROBOTS

    # every robot that patrols in both looks has moved on the map
    def moved() -> bool:
        now = markers(page)
        patrolling = [n for n in now if now[n]["state"] == "patrol" and first[n]["state"] == "patrol"]
        far = [
            n
            for n in patrolling
            if math.dist((now[n]["x"], now[n]["y"]), (first[n]["x"], first[n]["y"])) > 0.3
        ]
        return len(patrolling) >= ROBOTS - 2 and far == patrolling

    wait_until(moved, 60, "every patrolling robot's marker to move 0.3 m")
    # states arrive at 5 Hz or more (the API streams them at 10 Hz)
    period = stats(page)["update_period_ms"]
    assert period < 200, period


def test_reserved_segments_are_shown_with_traffic_on(page: Any) -> None:
    def reserved() -> int:
        text = page.find_element("id", "traffic-state").text
        return int(text.split()[0]) if text.split() and text.split()[0].isdigit() else 0

    assert wait_until(reserved, 60, "reserved roadmap segments on the page") > 0


def test_task_submitted_through_the_form_completes(page: Any, fleet: Fleet) -> None:
    form = page.find_element("id", "task-form")
    result = page.find_element("id", "task-result")
    # a bad target is refused, the field is named and marked, and nothing is stored
    before = len(fleet.get("/api/tasks"))
    page.find_element("id", "f-kind").send_keys("go_to")
    target = page.find_element("id", "f-target")
    target.clear()
    target.send_keys("no_such_place")
    page.find_element("id", "f-submit").click()
    wait_until(
        lambda: "target" in result.text and "err" in (result.get_attribute("class") or ""), 30, "the error"
    )
    assert "invalid" in (target.get_attribute("class") or "")
    assert len(fleet.get("/api/tasks")) == before

    # a go_to a roadmap node across the warehouse
    target.clear()
    target.send_keys("a7_2")
    form.find_element("id", "f-name").send_keys("browser test")
    page.find_element("id", "f-submit").click()
    task_id = wait_until(lambda: result.get_attribute("data-task-id"), 30, "the submitted task's id")
    assert fleet.get(f"/api/tasks/{task_id}")["spec"] == {
        "kind": "go_to",
        "target": "a7_2",
        "name": "browser test",
    }
    row = f'#tasks tbody tr[data-task-id="{task_id}"]'
    wait_until(lambda: page.find_elements("css selector", row), 30, f"{task_id} in the task table")

    def state() -> str:
        rows = page.find_elements("css selector", row)
        return rows[0].get_attribute("data-state") if rows else ""

    # 30 m at about 1 m/s is under 60 fleet s (15 wall s at SPEED 4); 8x margin on top
    wait_until(lambda: state() == "completed", 150, f"{task_id} to be completed on the page")
    task = fleet.get(f"/api/tasks/{task_id}")
    assert task["state"] == "completed" and task["robot"]
    assert result.get_attribute("data-state") == "completed"
    robot = markers(page)[task["robot"]]
    assert math.dist((robot["x"], robot["y"]), (24.0, 14.0)) < 1.5


def test_estop_stops_every_robot_until_release_and_resume(page: Any, fleet: Fleet) -> None:
    wait_until(
        lambda: page.find_element("id", "control-badge").get_attribute("data-state") == "running",
        30,
        "running",
    )
    page.find_element("id", "btn-estop").click()
    badge = page.find_element("id", "control-badge")
    wait_until(lambda: badge.get_attribute("data-state") == "estop", 30, "the e-stop badge")
    assert fleet.get("/api/fleet")["control"]["state"] == "estop"
    assert fleet.get("/api/fleet")["control"]["by"] == "dashboard"
    assert page.find_element("id", "btn-resume").get_attribute("disabled") is not None
    wait_until(
        lambda: all(m["state"] == "estop" for m in markers(page).values()), 60, "every robot in state estop"
    )
    # nothing moves: once the markers have caught up with the last motion (the page eases
    # each marker over one update period), they stay put over ten more updates from the fleet
    api = {r["name"]: r["pose"] for r in fleet.get("/api/robots")}
    n = robot_messages(page)
    wait_until(lambda: robot_messages(page) >= n + 3, 60, "three more robot updates")
    still = markers(page)
    n = robot_messages(page)
    wait_until(lambda: robot_messages(page) >= n + 10, 60, "ten more robot updates")
    later = markers(page)
    moved = {k: math.dist((still[k]["x"], still[k]["y"]), (later[k]["x"], later[k]["y"])) for k in still}
    assert max(moved.values()) < 1e-3, moved
    robots = fleet.get("/api/robots")
    assert all(r["mode"] == "estop" for r in robots)
    assert all(
        math.dist((r["pose"]["x"], r["pose"]["y"]), (api[r["name"]]["x"], api[r["name"]]["y"])) < 1e-3
        for r in robots
    )

    # release leaves the fleet paused; resume sets the robots going again
    page.find_element("id", "btn-release").click()
    wait_until(lambda: badge.get_attribute("data-state") == "paused", 30, "paused after release")
    page.find_element("id", "btn-resume").click()
    wait_until(lambda: badge.get_attribute("data-state") == "running", 30, "running after resume")
    wait_until(
        lambda: any(
            math.dist((m["x"], m["y"]), (later[k]["x"], later[k]["y"])) > 0.3
            for k, m in markers(page).items()
        ),
        60,
        "robots to move again after resume",
    )


def click_map_at(page: Any, x: float, y: float) -> None:
    """Click the map canvas at the map point (x, y) (m)."""
    from selenium.webdriver.common.action_chains import ActionChains

    canvas = page.find_element("id", "map")
    px, py = page.execute_script("return window.fleetDashboard.toScreen(arguments[0], arguments[1])", x, y)
    size = canvas.size
    ActionChains(page).move_to_element_with_offset(
        canvas, int(px - size["width"] / 2), int(py - size["height"] / 2)
    ).click().perform()


def test_form_builds_patrol_and_pick_and_the_table_cancels_them(page: Any, fleet: Fleet) -> None:
    from selenium.webdriver.support.ui import Select

    result = page.find_element("id", "task-result")
    kind = Select(page.find_element("id", "f-kind"))

    def submit() -> str:
        old = result.get_attribute("data-task-id")
        page.find_element("id", "f-submit").click()
        return str(
            wait_until(lambda: (v := result.get_attribute("data-task-id")) != old and v, 30, "a new task id")
        )

    page.find_element("id", "f-name").clear()
    # a patrol over typed waypoints, one lap, only robot3 may take it
    kind.select_by_value("patrol")
    Select(page.find_element("id", "f-route")).select_by_value("")
    page.find_element("id", "f-waypoints").send_keys("a2_s, a2_n, a3_n, a3_s")
    page.find_element("id", "f-laps").send_keys("1")
    Select(page.find_element("id", "f-robot")).select_by_value("robot3")
    patrol = submit()
    got = fleet.get(f"/api/tasks/{patrol}")
    assert got["spec"] == {
        "kind": "patrol",
        "waypoints": ["a2_s", "a2_n", "a3_n", "a3_s"],
        "laps": 1,
        "robot": "robot3",
    }

    # a pick whose stations are chosen by clicking them on the map
    kind.select_by_value("pick")
    Select(page.find_element("id", "f-robot")).select_by_value("")
    stations = {s["name"]: s for s in fleet.get("/api/stations")}
    for field, name in (("f-pickup", "pick_a4_1_w"), ("f-dropoff", "drop2")):
        page.find_element("id", field).click()
        click_map_at(page, stations[name]["x"], stations[name]["y"])
        wait_until(
            lambda f=field, n=name: page.find_element("id", f).get_attribute("value") == n,
            30,
            f"{field} = {name}",
        )
    dwell = page.find_element("id", "f-dwell")
    dwell.clear()
    dwell.send_keys("2")
    pick = submit()
    assert fleet.get(f"/api/tasks/{pick}")["spec"] == {
        "kind": "pick",
        "pickup": "pick_a4_1_w",
        "dropoff": "drop2",
        "dwell_s": 2.0,
    }

    # the table's cancel buttons cancel both
    for task_id in (patrol, pick):
        button = f'#tasks tbody tr[data-task-id="{task_id}"] button[data-cancel]'
        wait_until(
            lambda b=button: page.find_elements("css selector", b), 30, f"the cancel button of {task_id}"
        )
        page.find_element("css selector", button).click()
        row = f'#tasks tbody tr[data-task-id="{task_id}"]'
        wait_until(
            lambda r=row: page.find_element("css selector", r).get_attribute("data-state") == "canceled",
            60,
            f"{task_id} canceled on the page",
        )
        assert fleet.get(f"/api/tasks/{task_id}")["state"] == "canceled"


def test_page_reconnects_to_a_fleet_restarted_after_kill_9(tmp_path: Path, browser_ok: None) -> None:
    port = pick_free_port()
    first = start_fleet(tmp_path, port)
    try:
        with headless_chromium() as page:
            page.get(first.url + "/")
            wait_until(lambda: counts(page).get("markers") == ROBOTS, 90, f"{ROBOTS} robot markers")
            tasks = {t["id"] for t in first.get("/api/tasks")}
            first.proc.kill()
            first.proc.wait(15)
            body = page.find_element("tag name", "body")
            wait_until(
                lambda: body.get_attribute("data-ws") == "closed", 30, "the page to see the fleet gone"
            )
            second = start_fleet(tmp_path, port, "fleet2.log")
            try:
                wait_until(lambda: body.get_attribute("data-ws") == "open", 60, "the page to reconnect")
                # the restarted simulator puts robots back at their start: compare from there on
                n = robot_messages(page)
                wait_until(
                    lambda: robot_messages(page) >= n + 3, 60, "robot updates from the restarted fleet"
                )
                assert counts(page)["markers"] == ROBOTS
                before = markers(page)
                wait_until(
                    lambda: any(
                        math.dist((m["x"], m["y"]), (before[k]["x"], before[k]["y"])) > 0.3
                        for k, m in markers(page).items()
                    ),
                    60,
                    "markers to move again after the restart",
                )
                rows = {
                    r.get_attribute("data-task-id")
                    for r in page.find_elements("css selector", "#tasks tbody tr[data-task-id]")
                }
                assert tasks <= rows
            finally:
                stop_fleet(second)
    finally:
        if first.proc.poll() is None:
            stop_fleet(first)
