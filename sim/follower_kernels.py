"""The path follower's per-robot arithmetic as two compiled loops (:mod:`sim.kernels`).

:func:`track` does, robot by robot, what :class:`sim.follower.PathFollower`'s NumPy code does
before the detour search: advance the segment cursor, pass vias, detect the final position,
turn to the final yaw there, and for a driving robot the remaining path and the lookahead
point (returned as the offset from the robot, whose ``arctan2`` NumPy takes: see
:mod:`sim.kernels`). :func:`command` does what follows the detour: the turn-then-drive command,
the approach timer and the write-back into the state. Every float is computed by the same
operations in the same order as the NumPy code (``tests/sim/test_kernels.py`` compares whole
runs). Arrays are :class:`sim.state.FleetState`'s; ``F`` the following robots, increasing.
"""

from __future__ import annotations

import math

import numpy as np

from sim.kernels import jit, register_warm_up


@jit
def _load_segment(
    i: int,
    f_off: np.ndarray,
    f_seg: np.ndarray,
    pts_x: np.ndarray,
    pts_y: np.ndarray,
    seg_len: np.ndarray,
    suffix: np.ndarray,
    c_ax: np.ndarray,
    c_ay: np.ndarray,
    c_bx: np.ndarray,
    c_by: np.ndarray,
    c_ex: np.ndarray,
    c_ey: np.ndarray,
    c_den: np.ndarray,
    c_suf: np.ndarray,
    c_long: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """``FleetState.load_segments`` of robot ``i``."""
    k = f_off[i] + f_seg[i]
    ax = pts_x[k]
    ay = pts_y[k]
    bx = pts_x[k + 1]
    by = pts_y[k + 1]
    length = seg_len[k]
    c_ax[i] = ax
    c_ay[i] = ay
    c_bx[i] = bx
    c_by[i] = by
    c_ex[i] = bx - ax
    c_ey[i] = by - ay
    ll = length * length
    # NumPy's maximum: the second operand unless the first is greater
    c_den[i] = ll if ll > 1e-18 else 1e-18
    c_long[i] = length > 1e-9
    c_suf[i] = suffix[k + 1]


@jit
def _load_via(
    i: int,
    f_off: np.ndarray,
    f_voff: np.ndarray,
    f_vn: np.ndarray,
    f_nv: np.ndarray,
    vias: np.ndarray,
    pts_x: np.ndarray,
    pts_y: np.ndarray,
    c_vx: np.ndarray,
    c_vy: np.ndarray,
    c_vseg: np.ndarray,
    c_vmore: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """``FleetState.load_vias`` of robot ``i``."""
    vn = f_vn[i]
    nv = f_nv[i]
    vi = vias[f_voff[i] + (nv if nv < vn - 1 else vn - 1)]
    k = f_off[i] + vi
    c_vseg[i] = vi
    c_vx[i] = pts_x[k]
    c_vy[i] = pts_y[k]
    c_vmore[i] = nv < vn - 1


# long: one pass per robot over the stages the NumPy follower runs as array passes
@jit
def track(
    F: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    th: np.ndarray,
    v: np.ndarray,
    f_xy: np.ndarray,
    f_seg: np.ndarray,
    f_len: np.ndarray,
    f_off: np.ndarray,
    f_nv: np.ndarray,
    f_vn: np.ndarray,
    f_voff: np.ndarray,
    f_yaw: np.ndarray,
    c_ax: np.ndarray,
    c_ay: np.ndarray,
    c_bx: np.ndarray,
    c_by: np.ndarray,
    c_ex: np.ndarray,
    c_ey: np.ndarray,
    c_den: np.ndarray,
    c_suf: np.ndarray,
    c_long: np.ndarray,
    c_vx: np.ndarray,
    c_vy: np.ndarray,
    c_vseg: np.ndarray,
    c_vmore: np.ndarray,
    c_gx: np.ndarray,
    c_gy: np.ndarray,
    vias: np.ndarray,
    pts_x: np.ndarray,
    pts_y: np.ndarray,
    seg_len: np.ndarray,
    suffix: np.ndarray,
    tol: float,
    yaw_tol: float,
    max_w: float,
    max_alpha: float,
    seg_out: np.ndarray,
    nv_out: np.ndarray,
    proj_out: np.ndarray,
    rem_out: np.ndarray,
    dx_out: np.ndarray,
    dy_out: np.ndarray,
    w_out: np.ndarray,
    xy_out: np.ndarray,
    arrived_out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Cursors, arrival and lookahead of robots ``F`` (see the module docstring): the
    cursors ``f_seg`` / ``f_nv`` and the caches ``c_*`` are updated in place; per robot of
    ``F`` out: the cursors, the projection parameter, the remaining path (m, 0 at the final
    position), the lookahead point's offset from the robot (m, driving robots), the turn
    command (rad/s, robots at their final position), whether it is there and whether it
    arrived. ``tol``, ``yaw_tol``: the goal tolerances (m, rad); ``max_w``, ``max_alpha``: the
    robot's angular speed and acceleration limits."""
    two_alpha = 2.0 * max_alpha
    for r in range(F.shape[0]):
        i = F[r]
        X = x[i]
        Y = y[i]
        xy = f_xy[i]
        act = not xy
        seg = f_seg[i]
        last = f_len[i] - 2
        if c_long[i]:
            t = ((X - c_ax[i]) * c_ex[i] + (Y - c_ay[i]) * c_ey[i]) / c_den[i]
        else:
            t = 1.0
        if act:
            while seg < last and (t >= 1.0 or math.hypot(c_bx[i] - X, c_by[i] - Y) <= tol):
                seg += 1
                f_seg[i] = seg
                _load_segment(
                    i, f_off, f_seg, pts_x, pts_y, seg_len, suffix,
                    c_ax, c_ay, c_bx, c_by, c_ex, c_ey, c_den, c_suf, c_long,
                )  # fmt: skip
                if c_long[i]:
                    t = ((X - c_ax[i]) * c_ex[i] + (Y - c_ay[i]) * c_ey[i]) / c_den[i]
                else:
                    t = 1.0
        proj = t if t > 0.0 else 0.0
        proj = proj if proj < 1.0 else 1.0
        nv = f_nv[i]
        if act and c_vmore[i] and (seg >= c_vseg[i] or math.hypot(c_vx[i] - X, c_vy[i] - Y) <= tol):
            while True:
                nv += 1
                f_nv[i] = nv
                _load_via(i, f_off, f_voff, f_vn, f_nv, vias, pts_x, pts_y, c_vx, c_vy, c_vseg, c_vmore)
                near = math.hypot(c_vx[i] - X, c_vy[i] - Y) <= tol
                if not (c_vmore[i] and (seg >= c_vseg[i] or near)):
                    break
        if act and not c_vmore[i] and math.hypot(c_gx[i] - X, c_gy[i] - Y) <= tol:
            xy = True
        seg_out[r] = seg
        nv_out[r] = nv
        proj_out[r] = proj
        xy_out[r] = xy
        arrived_out[r] = False
        rem_out[r] = 0.0
        w_out[r] = 0.0
        if xy:
            err = (f_yaw[i] - th[i] + math.pi) % (2.0 * math.pi) - math.pi
            done = abs(err) <= yaw_tol
            arrived_out[r] = done
            if not done:
                turn = math.sqrt(two_alpha * abs(err))
                w_out[r] = math.copysign(max_w if max_w < turn else turn, err)
            continue
        ax = c_ax[i]
        ay = c_ay[i]
        bx = c_bx[i]
        by = c_by[i]
        qx = ax + proj * c_ex[i]
        qy = ay + proj * c_ey[i]
        left = math.hypot(bx - qx, by - qy)
        rem_out[r] = left + c_suf[i] + math.hypot(qx - X, qy - Y)
        dist = 0.3 + 0.3 * abs(v[i])
        if dist > left and seg < last:
            s = seg
            off = f_off[i]
            while True:
                dist = dist - left
                s += 1
                k = off + s
                qx = pts_x[k]
                qy = pts_y[k]
                bx = pts_x[k + 1]
                by = pts_y[k + 1]
                left = seg_len[k]
                if not (dist > left and s < last):
                    break
        if dist >= left:
            f = 1.0
        else:
            f = dist / (left if left > 1e-12 else 1e-12)
        dx_out[r] = qx + f * (bx - qx) - X
        dy_out[r] = qy + f * (by - qy) - Y


# long: the steering, the approach timer and the write-back of every robot in one pass
@jit
def command(
    F: np.ndarray,
    di: np.ndarray,
    desired: np.ndarray,
    th: np.ndarray,
    seg_out: np.ndarray,
    nv_out: np.ndarray,
    proj_out: np.ndarray,
    rem_out: np.ndarray,
    w_out: np.ndarray,
    xy_out: np.ndarray,
    arrived_out: np.ndarray,
    side: np.ndarray,
    vmax: float,
    max_w: float,
    max_acc: float,
    max_alpha: float,
    rot_rad: float,
    gain: float,
    approach: float,
    now: float,
    window: float,
    f_seg: np.ndarray,
    f_nv: np.ndarray,
    f_side: np.ndarray,
    f_t: np.ndarray,
    f_best: np.ndarray,
    f_btime: np.ndarray,
    f_xy: np.ndarray,
    vd: np.ndarray,
    wd: np.ndarray,
    drives: np.ndarray,
    stop: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Turn-then-drive for the driving robots ``F[di]`` heading for ``desired`` (rad, one per
    ``di``): rotate in place above ``rot_rad`` of heading error, else drive slower with the
    error and to stop at the end of the path (``gain``: rad/s per rad of error); then every
    robot of ``F``'s approach timer (its remaining path must shrink by ``approach`` m within
    ``window`` s, a robot at its final position always counts as progressing) and the
    write-back of cursors, flags and commands into the state arrays. ``stop[r]``: robot
    ``F[r]`` stopped this step (arrived, or no approach)."""
    two_alpha = 2.0 * max_alpha
    two_acc = 2.0 * max_acc * 0.8
    vcmd = np.zeros(F.shape[0])
    wcmd = w_out.copy()
    for q in range(di.shape[0]):
        r = di[q]
        err = (desired[q] - th[F[r]] + math.pi) % (2.0 * math.pi) - math.pi
        aerr = abs(err)
        if aerr > rot_rad:
            turn = math.sqrt(two_alpha * aerr)
            wcmd[r] = math.copysign(max_w if max_w < turn else turn, err)
        else:
            vdrive = vmax * (1.0 - 0.6 * aerr / rot_rad)
            cap = math.sqrt(two_acc * rem_out[r])
            vcmd[r] = vdrive if vdrive < cap else cap
            # np.clip: NumPy's maximum, then minimum
            wdrive = gain * err
            wdrive = wdrive if wdrive > -max_w else -max_w
            wcmd[r] = wdrive if wdrive < max_w else max_w
    for r in range(F.shape[0]):
        i = F[r]
        xy = xy_out[r]
        if xy or rem_out[r] < f_best[i] - approach:
            f_best[i] = rem_out[r]
            f_btime[i] = now
        halt = arrived_out[r] or now - f_btime[i] >= window - 1e-9
        stop[r] = halt
        if halt:
            vcmd[r] = 0.0
            wcmd[r] = 0.0
        f_seg[i] = seg_out[r]
        f_nv[i] = nv_out[r]
        f_side[i] = side[r]
        f_t[i] = proj_out[r]
        f_xy[i] = xy
        vd[i] = vcmd[r]
        wd[i] = wcmd[r]
        drives[i] = vcmd[r] != 0.0


# long: the corridor test of the follower's way, robot by robot and pair by pair
@jit
def way_blocked(
    fi: np.ndarray,
    desired: np.ndarray,
    rem: np.ndarray,
    side: np.ndarray,
    n: int,
    pi: np.ndarray,
    pj: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    reach2: float,
    contact: float,
    lat: float,
    look: float,
    margin: float,
    tol: float,
    hx: np.ndarray,
    hy: np.ndarray,
    best: np.ndarray,
    blocked_out: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """What ``PathFollower._avoid`` asks of ``Avoidance.corridor_free`` and then tests, for a
    step without dynamic obstacles: robot ``fi[q]`` heading for ``desired[q]`` (rad) is
    blocked when the first robot in its corridor is closer than ``look`` m and that, plus
    ``margin`` and then ``tol`` m, is short of its remaining path ``rem[q]``. The corridor
    test is :func:`sim.kernels.corridor_min`'s over the directed pairs ``(pi[p], pj[p])``
    with ``d2 < reach2``, their offsets computed from the positions ``x``, ``y`` as
    :func:`sim.kernels.short_pairs` computes them. Unblocked robots get ``side[q] = 0``; the
    blocked ones' ``q`` are written to ``blocked_out`` in order, and their number returned.
    ``hx``, ``hy``, ``best``: scratch of at least ``n``."""
    for i in range(n):
        hx[i] = 0.0
        hy[i] = 0.0
        best[i] = 0.0
    for q in range(fi.shape[0]):
        i = fi[q]
        hx[i] = math.cos(desired[q])
        hy[i] = math.sin(desired[q])
        best[i] = look
    cc = contact * contact
    lim = look + contact
    inf = math.inf
    # branch-free: which pairs count is a coin toss per pair, and a mispredicted branch costs
    # more than computing the gap of every pair; a robot that is not following has heading
    # (0, 0), so along = 0 and none of its pairs counts
    for p in range(pi.shape[0]):
        i = pi[p]
        hxa = hx[i]
        hya = hy[i]
        j = pj[p]
        dx = x[j] - x[i]
        dy = y[j] - y[i]
        along = dx * hxa + dy * hya
        lateral = abs(dx * hya - dy * hxa)
        hit = (dx * dx + dy * dy < reach2) & (along > 0.0) & (lateral < lat) & (along < lim)
        gap = along - contact if lateral >= contact else along - math.sqrt(max(cc - lateral * lateral, 0.0))
        g = max(0.0, gap) if hit else inf
        b = best[i]
        best[i] = g if g < b else b
    nb = 0
    for q in range(fi.shape[0]):
        b = best[fi[q]]
        if b < look and b + margin + tol < rem[q]:
            blocked_out[nb] = q
            nb += 1
        else:
            side[q] = 0
    return nb


def warm_up() -> None:
    """Compile (or load from the cache) :func:`track`, :func:`command` and :func:`way_blocked` with the argument
    types the follower passes, on empty inputs."""
    ints = np.zeros(0, dtype=np.int64)
    floats = np.zeros(0)
    flags = np.zeros(0, dtype=bool)
    track(
        ints, floats, floats, floats, floats, flags, ints, ints, ints, ints, ints, ints, floats,
        floats, floats, floats, floats, floats, floats, floats, floats, flags,
        floats, floats, ints, flags, floats, floats,
        ints, floats, floats, floats, floats,
        0.1, 0.1, 1.0, 1.0,
        ints, ints, floats, floats, floats, floats, floats, flags, flags,
    )  # fmt: skip
    command(
        ints, ints, floats, floats, ints, ints, floats, floats, floats, flags, flags, ints,
        1.0, 1.0, 1.0, 1.0, 0.8, 2.5, 0.1, 0.0, 20.0,
        ints, ints, ints, floats, floats, floats, flags, floats, floats, flags, flags,
    )  # fmt: skip
    way_blocked(
        ints, floats, floats, ints, 0, ints, ints, floats, floats, 1.0, 0.6, 0.65, 1.5, 0.6, 0.1,
        floats, floats, floats, ints,
    )  # fmt: skip


register_warm_up(warm_up)
