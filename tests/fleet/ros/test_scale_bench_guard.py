"""The ROS scale bench's hang guard (``bench/bench_ros_scale.py``, ``RowGuard``): a row that
blocks is never silent. Blocked in Python-visible waiting, the bench prints a clear error and
every thread's stack and exits 3; blocked in C code that holds the GIL (as a call into rclpy
can), faulthandler's own thread still dumps the stacks and exits. Real processes, real
blocking calls; no ROS needed. No timing is asserted beyond the hang guards."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parents[3] / "bench" / "bench_ros_scale.py"
#: Hang guard (wall s) for the guarded child to end by itself.
END_S = 120.0


def _guarded(block: str) -> subprocess.CompletedProcess[str]:
    """Run ``block`` under a ``RowGuard`` of 1 s (grace 1 s) in a child process."""
    code = (
        "import importlib.util, sys\n"
        f"spec = importlib.util.spec_from_file_location('bench_ros_scale', {str(BENCH)!r})\n"
        "bench = importlib.util.module_from_spec(spec); spec.loader.exec_module(bench)\n"
        "with bench.RowGuard(1.0, 'robots=200 test', grace_s=1.0):\n"
        f"    {block}\n"
        "print('row ended')\n"
    )
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=END_S)


def test_a_blocked_row_ends_with_a_clear_error_and_its_stack() -> None:
    res = _guarded("import threading; threading.Event().wait()  # never set")
    assert res.returncode == 3
    assert "error: row robots=200 test did not end within 1 s" in res.stderr
    assert 'File "<string>", line 5 in <module>' in res.stderr and "in wait" in res.stderr  # blocked there
    assert "row ended" not in res.stdout


def test_a_row_blocked_in_c_holding_the_gil_still_dumps_and_exits() -> None:
    """``ctypes.PyDLL`` keeps the GIL during the call: the watchdog thread cannot run."""
    res = _guarded("import ctypes; ctypes.PyDLL(None).sleep(600)")
    assert res.returncode == 1
    assert "Timeout" in res.stderr and "<string>" in res.stderr  # faulthandler's dump


def test_a_row_that_ends_is_left_alone() -> None:
    res = _guarded("pass")
    assert res.returncode == 0 and res.stdout == "row ended\n"
