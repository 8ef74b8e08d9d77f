"""Headless Chromium on the dashboard: the system's ``chromium`` and ``chromedriver``
(Debian's ``chromium`` and ``chromium-driver``, installed by ``tools/setup_browser.sh``) driven
by selenium. Nothing here downloads a browser or a driver: both are found on ``PATH`` or named
by ``FLEET_CHROMIUM`` / ``FLEET_CHROMEDRIVER``.

Used by the browser tests, ``bench/bench_dashboard.py`` and the screenshot command::

    python -m fleet.dashboard.browser http://127.0.0.1:8080/ --screenshot out/dashboard.png
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from fleet.errors import FleetError

if TYPE_CHECKING:
    from selenium.webdriver.remote.webdriver import WebDriver

T = TypeVar("T")

#: Browser window size (CSS px) unless asked otherwise: the dashboard's intended desktop view.
WINDOW = (1600, 1000)


class BrowserUnavailable(FleetError):
    """No headless Chromium can be started here (the message says what is missing)."""


@dataclass(frozen=True)
class Programs:
    """Where the browser and its driver are."""

    chromium: str
    chromedriver: str


def find_programs() -> Programs:
    """The system's Chromium and chromedriver; :class:`BrowserUnavailable` naming what is
    missing and how to install it."""
    chromium = os.environ.get("FLEET_CHROMIUM") or next(
        (p for p in map(shutil.which, ("chromium", "chromium-browser")) if p), None
    )
    driver = os.environ.get("FLEET_CHROMEDRIVER") or shutil.which("chromedriver")
    missing = [n for n, p in (("chromium", chromium), ("chromedriver", driver)) if not p]
    if missing or chromium is None or driver is None:
        raise BrowserUnavailable(
            f"{' and '.join(missing)} not found: run `make setup-browser` (Debian: apt-get install "
            "chromium chromium-driver) or set FLEET_CHROMIUM / FLEET_CHROMEDRIVER"
        )
    try:
        import selenium  # noqa: F401
    except ImportError:
        raise BrowserUnavailable("the selenium package is missing: pip install -e '.[dev]'") from None
    return Programs(chromium, driver)


@contextmanager
def headless_chromium(window: tuple[int, int] = WINDOW, scale: float = 1.0) -> Iterator[WebDriver]:
    """A headless Chromium driven by selenium, its page viewport ``window`` CSS pixels at
    ``scale`` device pixels per CSS pixel; always quit on exit."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    progs = find_programs()
    opts = webdriver.ChromeOptions()
    opts.binary_location = progs.chromium
    for arg in (
        "--headless=new",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-dev-shm-usage",
        "--hide-scrollbars",
        "--no-first-run",
        "--disable-extensions",
        "--disable-background-networking",
        "--disable-renderer-backgrounding",
        "--disable-background-timer-throttling",
        f"--force-device-scale-factor={scale}",
        f"--window-size={window[0]},{window[1]}",
    ):
        opts.add_argument(arg)
    driver = webdriver.Chrome(options=opts, service=Service(executable_path=progs.chromedriver))
    try:
        driver.execute_cdp_cmd(
            "Emulation.setDeviceMetricsOverride",
            {"width": window[0], "height": window[1], "deviceScaleFactor": scale, "mobile": False},
        )
        yield driver
    finally:
        driver.quit()


def wait_until(fn: Callable[[], T | None], timeout: float, what: str, step: float = 0.05) -> T:
    """The first truthy ``fn()``, checked every ``step`` s; ``TimeoutError`` naming ``what``
    after ``timeout`` s (exceptions from ``fn`` count as not yet)."""
    deadline = time.monotonic() + timeout
    last: BaseException | None = None
    while True:
        try:
            v = fn()
            if v:
                return v
        except Exception as e:  # noqa: BLE001 - the page may still be loading
            last = e
        if time.monotonic() > deadline:
            raise TimeoutError(
                f"timed out after {timeout:.0f} s waiting for {what}" + (f" ({last})" if last else "")
            )
        time.sleep(step)


def counts(driver: WebDriver) -> dict[str, Any]:
    """``{robots, markers, frames, tasks}`` as the page has them (``window.fleetDashboard``)."""
    v = driver.execute_script("return window.fleetDashboard ? window.fleetDashboard.counts() : null")
    return dict(v) if isinstance(v, dict) else {}


def stats(driver: WebDriver) -> dict[str, Any]:
    """The page's timing figures (message handling, frame time; ms) and message counts."""
    v = driver.execute_script("return window.fleetDashboard ? window.fleetDashboard.stats() : null")
    return dict(v) if isinstance(v, dict) else {}


def open_dashboard(driver: WebDriver, url: str, robots: int | None, timeout: float) -> dict[str, Any]:
    """Load ``url`` and wait until the page draws ``robots`` markers (any, when ``None``)."""
    driver.get(url)

    def ready() -> dict[str, Any] | None:
        c = counts(driver)
        n = c.get("markers", 0)
        return c if n and (robots is None or n == robots) else None

    return wait_until(ready, timeout, f"the dashboard at {url} to draw {robots or 'its'} robots")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m fleet.dashboard.browser",
        description="Open a running fleet's dashboard in headless Chromium: save a screenshot, print its figures.",
    )
    ap.add_argument("url", help="the dashboard, e.g. http://127.0.0.1:8080/")
    ap.add_argument("--screenshot", type=Path, help="write a PNG of the page here")
    ap.add_argument("--size", default=f"{WINDOW[0]}x{WINDOW[1]}", help="viewport WxH in CSS px")
    ap.add_argument("--scale", type=float, default=1.0, help="device pixels per CSS pixel (2: sharper PNG)")
    ap.add_argument(
        "--settle", type=float, default=2.0, help="seconds to watch the page after it drew the robots"
    )
    ap.add_argument("--select", help="select this robot (its details panel opens)")
    ap.add_argument("--timeout", type=float, default=60.0)
    args = ap.parse_args(argv)
    w, _, h = args.size.partition("x")
    try:
        with headless_chromium((int(w), int(h)), args.scale) as d:
            c = open_dashboard(d, args.url, None, args.timeout)
            if args.select:
                d.execute_script("window.fleetDashboard.select(arguments[0])", args.select)
            frames = c["frames"]
            wait_until(lambda: counts(d).get("frames", 0) >= frames + 5, args.timeout, "frames")
            time.sleep(args.settle)
            print(stats(d))
            if args.screenshot:
                args.screenshot.parent.mkdir(parents=True, exist_ok=True)
                d.save_screenshot(str(args.screenshot))
                print(f"wrote {args.screenshot}")
    except (BrowserUnavailable, TimeoutError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
