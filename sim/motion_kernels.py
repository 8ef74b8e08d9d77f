"""The step's motion stages as two compiled loops over every robot (:mod:`sim.kernels`), for
steps without dynamic obstacles (with one, the NumPy code of :mod:`sim.simulator` and
:mod:`sim.safety` runs).

:func:`limit_and_look` does what ``Simulator._limits`` does (acceleration and speed limits,
zero for a stalled, halted or flat robot) and prepares the reactive stop's corridor check
(:meth:`sim.safety.Safety.reactive_stop`): for each moving robot the look-ahead distance and
its unit heading in the direction of travel. After the corridor test of every neighbor pair
(:func:`sim.kernels.corridor_min`), :func:`stop_and_move` cuts the speeds to what can stop
before the robot ahead and integrates the move, refusing or sliding moves that would put the
footprint on a static obstacle (:meth:`sim.safety.Safety.move`). Same floats as the NumPy
code: same operations in the same order, NumPy's ``minimum`` / ``maximum`` rule (the second
operand when equal), the C library's ``cos`` / ``sin`` / ``sqrt`` / ``hypot``.
"""

from __future__ import annotations

import math

import numpy as np

from sim.kernels import jit, register_warm_up


@jit
def limit_and_look(
    vd: np.ndarray,
    wd: np.ndarray,
    v0: np.ndarray,
    w0: np.ndarray,
    stalled: np.ndarray,
    halt: np.ndarray,
    battery: np.ndarray,
    th: np.ndarray,
    dt: float,
    max_acc: float,
    max_alpha: float,
    vmax: float,
    max_w: float,
    stop_gap: float,
    v: np.ndarray,
    w: np.ndarray,
    hx: np.ndarray,
    hy: np.ndarray,
    look: np.ndarray,
) -> float:  # pragma: no cover - compiled
    """Limited commands ``v``, ``w`` of every robot; for the moving ones (``v != 0``) the
    reactive stop's look-ahead ``look`` (m) and heading ``(hx, hy)`` along the direction of
    travel, zeros for the others. Returns the longest look-ahead (0 when nobody moves)."""
    dv = max_acc * dt
    dw = max_alpha * dt
    two_acc = 2.0 * max_acc
    longest = 0.0
    for i in range(vd.shape[0]):
        a = v0[i] - dv
        x = vd[i] if vd[i] > a else a
        b = v0[i] + dv
        x = x if x < b else b
        x = x if x > -vmax else -vmax
        x = x if x < vmax else vmax
        a = w0[i] - dw
        z = wd[i] if wd[i] > a else a
        b = w0[i] + dw
        z = z if z < b else b
        z = z if z > -max_w else -max_w
        z = z if z < max_w else max_w
        if stalled[i] or halt[i] or battery[i] <= 0.0:
            x = 0.0
            z = 0.0
        v[i] = x
        w[i] = z
        if x != 0.0:
            direction = 1.0 if x > 0 else -1.0
            lk = x * x / two_acc + stop_gap + abs(x) * dt + 0.05
            look[i] = lk
            hx[i] = math.cos(th[i]) * direction
            hy[i] = math.sin(th[i]) * direction
            if lk > longest:
                longest = lk
        else:
            look[i] = 0.0
            hx[i] = 0.0
            hy[i] = 0.0
    return longest


@jit
def _free(
    x: float, y: float, gx: float, gy: float, res: float, width: int, height: int, cells: np.ndarray
) -> bool:  # pragma: no cover - compiled
    """``FootprintGrid.free`` of one position (``cells`` the padded free mask, flat)."""
    ix = math.floor((x - gx) / res)
    iy = math.floor((y - gy) / res)
    ix = ix if ix > -1 else -1
    ix = ix if ix < width else width
    iy = iy if iy > -1 else -1
    iy = iy if iy < height else height
    return cells[(iy + 1) * (width + 2) + ix + 1]  # type: ignore[no-any-return]


# long: the reactive cut, the move with its slide and the pose write-back, robot by robot
@jit
def stop_and_move(
    v: np.ndarray,
    w: np.ndarray,
    free_ahead: np.ndarray,
    look: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    th: np.ndarray,
    s_v: np.ndarray,
    s_w: np.ndarray,
    dist: np.ndarray,
    dt: float,
    max_acc: float,
    stop_gap: float,
    gx: float,
    gy: float,
    res: float,
    width: int,
    height: int,
    cells: np.ndarray,
    ds: np.ndarray,
    dth: np.ndarray,
    moved: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Cut each moving robot's ``v`` so it can stop ``stop_gap`` m before what is ahead
    (``free_ahead``, m, within ``look``), then move every robot by ``v``, ``w`` for ``dt``
    s at the mid-step heading: a move that puts the footprint off the free cells (``cells``,
    the padded grid of ``width`` x ``height`` cells of ``res`` m from ``(gx, gy)``) tries
    its larger axis alone, then the other, else is refused. Writes the pose, ``s_v``, ``s_w``
    and the odometer; out: the signed distance moved ``ds`` (m), the rotation ``dth`` (rad)
    and whether the robot translated."""
    two_acc = 2.0 * max_acc
    for i in range(v.shape[0]):
        vi = v[i]
        if vi != 0.0 and free_ahead[i] < look[i]:
            room = free_ahead[i] - stop_gap
            room = room if room > 0.0 else 0.0
            a = math.sqrt(two_acc * room)
            b = room / dt
            cap = a if a < b else b
            if abs(vi) > cap:
                vi = (1.0 if vi > 0 else -1.0) * cap
        dsi = vi * dt
        dthi = w[i] * dt
        mv = False
        if dsi != 0.0:
            ox = x[i]
            oy = y[i]
            mid = th[i] + 0.5 * dthi
            nx = ox + dsi * math.cos(mid)
            ny = oy + dsi * math.sin(mid)
            ok = _free(nx, ny, gx, gy, res, width, height, cells)
            if not ok:
                ex = nx - ox
                ey = ny - oy
                xfirst = abs(ex) >= abs(ey)
                for first in (True, False):
                    use_x = xfirst if first else not xfirst
                    cx = ox + ex if use_x else ox
                    cy = oy if use_x else oy + ey
                    if (cx != ox or cy != oy) and _free(cx, cy, gx, gy, res, width, height, cells):
                        nx = cx
                        ny = cy
                        ok = True
                        break
            if ok:
                step_len = math.hypot(nx - ox, ny - oy)
                dsi = math.copysign(step_len, dsi)
                vi = dsi / dt
                x[i] = nx
                y[i] = ny
                mv = True
            else:
                dsi = 0.0
                vi = 0.0
        th[i] = (th[i] + dthi + math.pi) % (2.0 * math.pi) - math.pi
        s_v[i] = vi
        s_w[i] = w[i]
        dist[i] += abs(dsi)
        ds[i] = dsi
        dth[i] = dthi
        moved[i] = mv


def warm_up() -> None:
    """Compile (or load from the cache) both kernels with the simulator's argument types."""
    f = np.zeros(0)
    b = np.zeros(0, dtype=bool)
    cells = np.zeros(9, dtype=bool)
    limit_and_look(f, f, f, f, b, b, f, f, 0.05, 1.0, 1.0, 1.0, 1.0, 0.1, f, f, f, f, f)
    stop_and_move(f, f, f, f, f, f, f, f, f, f, 0.05, 1.0, 0.1, 0.0, 0.0, 0.1, 1, 1, cells, f, f, b)


register_warm_up(warm_up)


# long: the battery, the charger test and the progress checker, robot by robot
@jit
def battery_and_progress(
    moved: np.ndarray,
    w: np.ndarray,
    ds: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    battery: np.ndarray,
    charging: np.ndarray,
    sites_x: np.ndarray,
    sites_y: np.ndarray,
    charger_radius: float,
    charge_step: float,
    drain_per_m: float,
    drain_step: float,
    px: np.ndarray,
    py: np.ndarray,
    pt: np.ndarray,
    stuck: np.ndarray,
    has_task: np.ndarray,
    drives: np.ndarray,
    fol: np.ndarray,
    f_xy: np.ndarray,
    now: float,
    progress_radius: float,
    stuck_time: float,
    stuck_out: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """``Simulator._battery`` and ``Simulator._check_progress`` of every robot in one pass.

    Battery: a robot that neither translated (``moved``) nor turned (``w == 0``) within
    ``charger_radius`` of a charger (``sites_x`` sorted, ``sites_y`` in the same order; the
    test of :func:`sim.spatial.near_any`) charges by ``charge_step`` up to 1; the others drain
    by ``drain_per_m * |ds| + drain_step`` down to 0 (``BatteryModel.integrate``'s floats).
    Progress: a robot farther than ``progress_radius`` from ``(px, py)`` made progress (mark
    moved there, its time ``now``, not stuck); one that is near and not trying to move has its
    time reset; one near and trying since ``stuck_time`` is appended to ``stuck_out``.
    Returns how many were appended (in increasing order)."""
    m = sites_x.shape[0]
    margin = charger_radius + 1e-9 * (1.0 + abs(charger_radius))
    ns = 0
    for i in range(x.shape[0]):
        xi = x[i]
        yi = y[i]
        ch = False
        if m and not moved[i] and w[i] == 0.0:
            # first site with sites_x >= xi - margin (searchsorted 'left'), then every one up
            # to xi + margin
            lo = 0
            hi = m
            key = xi - margin
            while lo < hi:
                mid = (lo + hi) // 2
                if sites_x[mid] < key:
                    lo = mid + 1
                else:
                    hi = mid
            top = xi + margin
            j = lo
            while j < m and sites_x[j] <= top:
                if math.hypot(sites_x[j] - xi, sites_y[j] - yi) <= charger_radius:
                    ch = True
                    break
                j += 1
        level = battery[i]
        if ch:
            c = level + charge_step
            battery[i] = 1.0 if 1.0 < c else c
        else:
            d = level - drain_per_m * abs(ds[i]) - drain_step
            battery[i] = 0.0 if 0.0 > d else d
        charging[i] = ch
        if math.hypot(xi - px[i], yi - py[i]) > progress_radius:
            px[i] = xi
            py[i] = yi
            pt[i] = now
            stuck[i] = False
        else:
            trying = has_task[i] and (drives[i] or (fol[i] and not f_xy[i]))
            if not trying:
                pt[i] = now
            elif now - pt[i] >= stuck_time - 1e-9:
                stuck_out[ns] = i
                ns += 1
    return ns


def warm_up_battery() -> None:
    """Compile (or load from the cache) :func:`battery_and_progress`."""
    f = np.zeros(0)
    b = np.zeros(0, dtype=bool)
    battery_and_progress(
        b, f, f, f, f, f, b, f, f, 0.5, 0.01, 0.001, 0.0001, f, f, f, b, b, b, b, b, 1.0, 0.1, 10.0,
        np.zeros(0, dtype=np.int64),
    )  # fmt: skip


register_warm_up(warm_up_battery)
