"""Loads the conformance harness plugins and parametrizes ``backend_name`` x ``case`` over
:data:`conformance_harness.BACKEND_FACTORIES` and :data:`fleet.testing.conformance.CASES`.

How to register another backend: add a file ``harness_<name>.py`` here that decorates a
context-manager factory with ``conformance_harness.register_backend("<name>")``; see the
docstring of ``conformance_harness.py``. Every ``harness_*.py`` file here is imported (sorted by
name) before the tests are parametrized; no edit of this file or of the tests is needed.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest
from conformance_harness import BACKEND_FACTORIES, LACKS, MARKS

from fleet.testing.conformance import CASES

#: The harness plugin modules, in load order.
PLUGINS: list[ModuleType] = []


def _load_plugins() -> None:
    here = Path(__file__).parent
    for path in sorted(here.glob("harness_*.py")):
        mod_name = f"_conformance_{path.stem}"
        if mod_name in sys.modules:
            PLUGINS.append(sys.modules[mod_name])
            continue
        spec = importlib.util.spec_from_file_location(mod_name, path)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[mod_name] = module
        spec.loader.exec_module(module)
        PLUGINS.append(module)


_load_plugins()


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    """One test per (backend, case); a case needing a capability the backend lacks is not
    generated for it (the reason is declared once, in its harness file)."""
    if not {"backend_name", "case"} <= set(metafunc.fixturenames):
        return
    params = [
        pytest.param(name, case, marks=MARKS[name], id=f"{name}-{case.name}")
        for name in sorted(BACKEND_FACTORIES)
        for case in CASES
        if not case.requires & set(LACKS[name])
    ]
    metafunc.parametrize(("backend_name", "case"), params)


def pytest_runtest_teardown(item: pytest.Item, nextitem: pytest.Item | None) -> None:
    """Tells each harness plugin that defines ``between_cases(next_backend)`` which backend the
    next test runs on (``None``: not a conformance test), so it can stop what it keeps ready."""
    callspec = getattr(nextitem, "callspec", None)
    next_backend = callspec.params.get("backend_name") if callspec is not None else None
    for module in PLUGINS:
        hook = getattr(module, "between_cases", None)
        if hook is not None:
            hook(next_backend)
