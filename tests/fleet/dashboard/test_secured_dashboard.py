"""The dashboard of a secured fleet (``fleet run --secure DIR --api ...``) in a real headless
Chromium: it shows the fleet without a token, its commands are refused (the note says how to
give the token) and change nothing; opened as ``/#token=<DIR/api.token>`` its buttons work and
the token leaves the address bar.

Real Zenoh on loopback, the real simulator and API; waits on conditions with deadlines. Without
the browser the test is skipped and says why (``make setup-browser`` installs it)."""

from __future__ import annotations

import json
import subprocess
import sys
import urllib.request
from pathlib import Path
from typing import Any

import pytest
from ports import free_endpoint, pick_free_port

from fleet.dashboard.browser import BrowserUnavailable, counts, find_programs, headless_chromium, wait_until

ROOT = Path(__file__).resolve().parents[3]
PATROL = ROOT / "configs" / "warehouse_patrol.yaml"

pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]


def get(url: str) -> Any:
    with urllib.request.urlopen(url, timeout=10) as r:
        return json.loads(r.read())


def test_secured_dashboard_commands_need_the_token(tmp_path: Path) -> None:
    try:
        find_programs()
    except BrowserUnavailable as e:
        pytest.skip(str(e))
    ep, port = free_endpoint(), pick_free_port()
    keys = tmp_path / "keys"
    fleet = [sys.executable, "-m", "fleet.cli"]
    init = subprocess.run(
        [*fleet, "keys", "init", str(PATROL), str(keys), "--robots", "2", "--endpoint", ep],
        cwd=ROOT, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert init.returncode == 0, init.stderr
    token = (keys / "api.token").read_text().strip()
    log = tmp_path / "fleet.log"
    url = f"http://127.0.0.1:{port}"
    with open(log, "wb") as out:
        proc = subprocess.Popen(
            [*fleet, "run", str(PATROL), "--robots", "2", "--no-live", "--speed", "2", "--duration", "7200",
             "--endpoint", ep, "--api", f"127.0.0.1:{port}", "--state", str(tmp_path / "state"),
             "--secure", str(keys)],
            cwd=ROOT, stdout=out, stderr=subprocess.STDOUT,
        )  # fmt: skip
    try:

        def up() -> bool:
            assert proc.poll() is None, log.read_text()
            try:
                return sum(r["pose"] is not None for r in get(url + "/api/robots")) == 2
            except OSError:
                return False

        wait_until(up, 120, "the API to list both robots", step=0.2)
        assert f"{url}/#token=<{keys.resolve()}/api.token>" in log.read_text()
        with headless_chromium() as page:
            page.get(url + "/")
            wait_until(lambda: counts(page).get("markers") == 2, 90, "two robot markers")  # reads are open
            page.find_element("id", "btn-pause").click()
            note = page.find_element("id", "control-note")
            wait_until(lambda: "#token=" in note.text, 30, "the note saying how to give the token")
            assert "secured" in note.text
            assert get(url + "/api/fleet")["control"]["state"] == "running"
            page.get(f"{url}/#token={token}")
            wait_until(lambda: counts(page).get("markers") == 2, 90, "two robot markers again")
            assert "token" not in page.current_url
            page.find_element("id", "btn-pause").click()
            badge = page.find_element("id", "control-badge")
            wait_until(lambda: badge.get_attribute("data-state") == "paused", 30, "the paused badge")
            assert get(url + "/api/fleet")["control"]["state"] == "paused"
    finally:
        proc.terminate()
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(15)
