"""Loads the conformance harness plugins and parametrizes the ``harness`` fixture over
:data:`conformance_harness.BACKEND_FACTORIES`.

How to register another backend (ROS 2 adapter, Zenoh bridge, SUMO): add a file
``tests/conformance/harness_<name>.py`` that decorates a context-manager factory with
``conformance_harness.register_backend("<name>")``; see the docstring of
``conformance_harness.py`` for the harness contract and an example. Every ``harness_*.py``
file here is imported (sorted by name) before the fixture is built; no edit of this file or
of the tests is needed.
"""

from __future__ import annotations

import importlib.util
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from conformance_harness import _MARKS, BACKEND_FACTORIES, LACKS, ConformanceHarness


def _load_plugins() -> None:
    here = Path(__file__).parent
    for path in sorted(here.glob("harness_*.py")):
        mod_name = f"_conformance_{path.stem}"
        if mod_name in sys.modules:
            continue
        spec = importlib.util.spec_from_file_location(mod_name, path)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[mod_name] = module
        spec.loader.exec_module(module)


_load_plugins()


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "requires(capability): the test needs a backend capability")


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    """Parametrize ``harness`` over every backend that has the capabilities the test requires."""
    if "harness" not in metafunc.fixturenames:
        return
    needs = {m.args[0] for m in metafunc.definition.iter_markers("requires")}
    names = [n for n in sorted(BACKEND_FACTORIES) if not needs & set(LACKS[n])]
    metafunc.parametrize("harness", [pytest.param(n, marks=_MARKS[n]) for n in names], indirect=True)


@pytest.fixture
def harness(request: pytest.FixtureRequest) -> Iterator[ConformanceHarness]:
    """A fresh harness of each registered backend."""
    with BACKEND_FACTORIES[request.param]() as h:
        yield h
