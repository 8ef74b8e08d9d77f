"""The navigation backend conformance suite: every registered backend must pass every case of
:data:`fleet.testing.conformance.CASES` (one test per backend and case, see ``conftest.py``)."""

from __future__ import annotations

from conformance_harness import BACKEND_FACTORIES, LACKS

from fleet.testing.conformance import Case, run_case


def test_backend_conformance(backend_name: str, case: Case) -> None:
    result = run_case(BACKEND_FACTORIES[backend_name], case, LACKS[backend_name])
    assert result.passed, f"{backend_name}: {case.doc}\n{result.reason}"
