"""How the suite runs in parallel (``pytest -n 2``, pytest-xdist; ``make test`` does it).

Each test gets one ``xdist_group`` so that, with ``--dist loadgroup``, a group runs on one
worker in its file's order:

* every ROS 2 test (marker ``ros``, the ROS conformance cases included) in one group ``ros``:
  only one worker ever runs ROS, so two workers' servers, DDS participants and private domains
  never meet, and no two ROS tests load the machine at once;
* the conformance cases of one backend in one group (``conformance-<backend>``): the server of
  the next case is started while the current one runs (``tests/fleet/testing/prestart.py``);
* every other test with the rest of its file: module-scoped fixtures (servers, fleets) start
  once per file, as in a serial run.

Tests marked ``serial`` (:data:`SERIAL_FILES`) need the machine to themselves: ``make test``
runs them after the parallel part, one at a time.
Without ``-n`` the whole suite runs in one process as before; nothing here changes a test.
"""

from __future__ import annotations

import pytest

#: Files whose tests need the machine to themselves (marked ``serial`` here): whole ROS fleets
#: over DDS whose lap and distance figures are compared with the in-process run. They must be
#: under ``tests/fleet/ros``: the Makefile's serial pass collects only that directory.
SERIAL_FILES = (
    "tests/fleet/ros/test_fleet_demo_ros.py",
    "tests/fleet/ros/test_ros_ground_truth.py",
)


def _group(item: pytest.Item) -> str:
    if item.get_closest_marker("ros") is not None:
        return "ros"
    callspec = getattr(item, "callspec", None)
    backend = callspec.params.get("backend_name") if callspec is not None else None
    if isinstance(backend, str):
        return f"conformance-{backend}"
    return item.nodeid.split("::", 1)[0]


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """``serial`` on the tests of :data:`SERIAL_FILES` (before ``-m`` selects) and one
    ``xdist_group`` per test (above, before xdist reads them)."""
    xdist = config.pluginmanager.hasplugin("xdist")
    for item in items:
        if item.nodeid.split("::", 1)[0] in SERIAL_FILES:
            item.add_marker(pytest.mark.serial)
        if xdist and item.get_closest_marker("xdist_group") is None:
            item.add_marker(pytest.mark.xdist_group(_group(item)))
