"""The batch read's per-goal loop compiled (:mod:`sim.kernels`): the rows of
:meth:`sim.batch.SimBatch.query_batch` answered from the status arrays, in one pass instead of
a dozen gathers over the whole fleet.

:func:`goal_rows` does what :meth:`sim.batch.SimBatch._goals` does with NumPy for the goals
that are their robot's latest motion goal and run as a planned navigation: the status code and
the remaining path length (:func:`sim.batch._path_remaining`, the same floats: the same
operations in the same order, the C library's ``hypot``); it lists the other goals (finished,
older, other tasks), which read their record in Python.
"""

from __future__ import annotations

import math

import numpy as np

from sim.kernels import jit, register_warm_up


# long: one pass per goal over the test and the remaining path the NumPy code does as array passes
@jit
def goal_rows(
    rows: np.ndarray,
    nums: np.ndarray,
    g_num: np.ndarray,
    g_code: np.ndarray,
    g_nav: np.ndarray,
    terminal: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    f_t: np.ndarray,
    c_ax: np.ndarray,
    c_ay: np.ndarray,
    c_bx: np.ndarray,
    c_by: np.ndarray,
    c_suf: np.ndarray,
    f_xy: np.ndarray,
    f_len: np.ndarray,
    status: np.ndarray,
    remaining: np.ndarray,
    slow: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """For each goal ``k`` (robot row ``rows[k]``, -1: none; number ``nums[k]``): when it is
    its robot's latest motion goal (``g_num``), running (``terminal[g_code]`` false) as a
    planned navigation (``g_nav``), write its status code to ``status[k]`` and its remaining
    path (m; 0 at the final position or on a path of fewer than 2 points) to
    ``remaining[k]``; otherwise, for a goal with a robot row, append ``k`` to ``slow``.
    Returns how many were appended."""
    ns = 0
    for k in range(rows.shape[0]):
        r = rows[k]
        if r < 0:
            continue
        code = g_code[r]
        num = nums[k]
        if g_num[r] == num and num > 0 and g_nav[r] and not (code >= 0 and terminal[code]):
            status[k] = code
            if f_xy[r] or f_len[r] < 2:
                remaining[k] = 0.0
            else:
                t = f_t[r]
                ax = c_ax[r]
                ay = c_ay[r]
                bx = c_bx[r]
                by = c_by[r]
                qx = ax + t * (bx - ax)
                qy = ay + t * (by - ay)
                remaining[k] = math.hypot(bx - qx, by - qy) + c_suf[r] + math.hypot(qx - x[r], qy - y[r])
        else:
            slow[ns] = k
            ns += 1
    return ns


def warm_up() -> None:
    """Compile (or load from the cache) :func:`goal_rows` with the batch read's argument types."""
    ints = np.zeros(0, dtype=np.int64)
    rows = np.zeros(0, dtype=np.intp)
    f = np.zeros(0)
    b = np.zeros(0, dtype=bool)
    goal_rows(
        rows, ints, ints, ints, b, np.zeros(1, dtype=bool), f, f, f, f, f, f, f, f, b, ints,
        np.zeros(0, dtype=np.int8), f, ints,
    )  # fmt: skip


register_warm_up(warm_up)
