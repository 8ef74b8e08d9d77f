"""The dashboard's files are served at ``/`` of an app after its API routes, and every one
of them ships as package data."""

from __future__ import annotations

import fnmatch
import tomllib
from pathlib import Path

import pytest
from fastapi import FastAPI
from fastapi.responses import HTMLResponse
from fastapi.testclient import TestClient

from fleet import dashboard

ROOT = Path(__file__).resolve().parents[3]


def app_with_placeholder() -> FastAPI:
    app = FastAPI()

    @app.get("/api/robots")
    async def robots() -> list[dict[str, str]]:
        return [{"name": "robot1"}]

    @app.get("/")
    async def index() -> HTMLResponse:
        return HTMLResponse("the API alone")

    return app


def test_mount_serves_the_page_its_scripts_and_keeps_the_api() -> None:
    app = app_with_placeholder()
    dashboard.mount(app)
    client = TestClient(app)
    page = client.get("/")
    assert page.status_code == 200
    assert 'id="map"' in page.text and "the API alone" not in page.text
    for src in (
        "js/main.js",
        "js/mapview.js",
        "js/fleet.js",
        "js/panels.js",
        "js/taskform.js",
        "dashboard.css",
    ):
        r = client.get(f"/{src}")
        assert r.status_code == 200, src
        assert len(r.content) > 200, src
    assert client.get("/js/main.js").headers["content-type"].split(";")[0] in (
        "text/javascript",
        "application/javascript",
    )
    assert client.get("/api/robots").json() == [{"name": "robot1"}]
    assert client.get("/no-such-file.js").status_code == 404


def test_every_module_the_page_imports_exists() -> None:
    static = dashboard.STATIC_DIR
    html = (static / "index.html").read_text()
    assert 'src="js/main.js"' in html
    for js in (static / "js").glob("*.js"):
        for line in js.read_text().splitlines():
            if line.startswith("import ") and " from " in line:
                target = line.rsplit(" from ", 1)[1].strip(" \";'")
                assert (js.parent / target).is_file(), f"{js.name} imports {target}"


def test_mount_of_a_directory_without_index_names_it(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="index.html"):
        dashboard.mount(FastAPI(), tmp_path)


def test_every_static_file_is_package_data() -> None:
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())
    patterns = cfg["tool"]["setuptools"]["package-data"]["fleet.dashboard"]
    pkg = dashboard.STATIC_DIR.parent
    files = [p.relative_to(pkg).as_posix() for p in dashboard.STATIC_DIR.rglob("*") if p.is_file()]
    assert len(files) >= 7
    unshipped = [f for f in files if not any(fnmatch.fnmatch(f, pat) for pat in patterns)]
    assert unshipped == []
