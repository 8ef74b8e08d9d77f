"""The live web dashboard of a running fleet: static files (HTML, CSS, JavaScript; no CDN)
shipped in this package and served at ``/`` of the task service's HTTP API.

The page reads only the API (``docs/dashboard.md``): the site once (``/api/map``,
``/api/map.png``, ``/api/roadmap``, ``/api/chargers``, ``/api/stations``, ``/api/routes``),
then ``/api/ws`` for robot states (at the API's ``ws_hz``), task events, control changes and
reserved roadmap segments; it posts tasks to ``/api/tasks`` and commands to
``/api/fleet/pause|resume|estop|release``. It draws the map on a ``<canvas>`` in batches by
colour, so 1000 robots at 10 Hz stay smooth (``bench/bench_dashboard.py``).

:func:`mount` serves it on a FastAPI (Starlette) app after the API's routes.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from starlette.applications import Starlette

#: The dashboard's files (``index.html`` and what it loads).
STATIC_DIR = Path(__file__).resolve().parent / "static"


def mount(app: Starlette, directory: Path | None = None) -> None:
    """Serve the dashboard (``directory``, default :data:`STATIC_DIR`) at ``/`` of ``app``.

    Call it after every API route is added: a mount at ``/`` answers every path no earlier
    route took. A plain ``GET /`` route that an app added as a placeholder is removed first,
    so the dashboard answers ``/``. Raises ``FileNotFoundError`` if the directory has no
    ``index.html`` (a broken install: the package data is missing)."""
    from starlette.routing import Route
    from starlette.staticfiles import StaticFiles

    root = directory or STATIC_DIR
    if not (root / "index.html").is_file():
        raise FileNotFoundError(f"{root / 'index.html'}: the dashboard's files are missing from the install")
    app.router.routes[:] = [r for r in app.router.routes if not (isinstance(r, Route) and r.path == "/")]
    app.mount("/", StaticFiles(directory=root, html=True), name="dashboard")


__all__ = ["STATIC_DIR", "mount"]
