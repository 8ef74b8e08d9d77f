"""The detour search's blocked headings in one compiled pass (:mod:`sim.kernels`): the
neighbors' corridor test of every (pair, offset) and the static map's footprint samples of
the offsets still free, which :class:`sim.avoidance.Avoidance` otherwise runs as
:func:`sim.kernels.pair_blocks` followed by NumPy passes (``Avoidance._static_blocks``).

Same bits, one ``cos`` / ``sin`` per blocked robot. The pair test of heading ``h = db + o_k``
needs a neighbor's distance along the heading and across it. Rather than the unit vector of
every one of the 12 headings (12 ``cos`` / ``sin`` per blocked robot, most of the pass's time
in a jam), the neighbor's offset is turned once into the frame of the wanted heading ``db``
(``a`` along, ``b`` across) and the offsets' fixed cosines and sines turn it further: along
``a cos(o_k) + b sin(o_k)``, across ``|a sin(o_k) - b cos(o_k)|`` (:func:`_rotated_blocks`).
These differ from what the heading's own ``cos(db + o_k)`` gives by rounding only: a few ulp
of the unit vectors (and the rounding of ``db + o_k`` itself), under 1e-14 m for neighbors
within the pair reach (about 1.5 m). A decision is taken from them only when every quantity it
compares (along against 0 and the corridor's length, across against the corridor's half-width
and the contact distance, the gap against the clearance) is at least :data:`MARGIN_M` from its
threshold, where a 1e-14 m error cannot flip it (the gap test is taken squared, without a
square root, and is near its threshold within ``2 contact MARGIN_M``, see
:func:`_rotated_blocks`); otherwise the exact test runs with the heading's C library ``cos`` / ``sin``
(:func:`_exact_block`, :func:`sim.kernels.pair_blocks_along`'s formula). So the blocked bits
are those of :func:`sim.kernels.pair_blocks` on every input, and the loop over the 12
offsets is branch-free (selects, no early exits), which the compiler vectorizes.

The static test samples the same points (``x + cos(h) * d``, the heading's C library
``cos`` / ``sin``) on the same padded footprint mask
(:meth:`sim.footprint.FootprintGrid.free`); a robot whose cell is in the clear
(:meth:`sim.footprint.FootprintGrid.clear`) is not sampled.
"""

from __future__ import annotations

import math

import numpy as np

from sim.follower_kernels import way_blocked
from sim.kernels import jit, register_warm_up
from sim.motion_kernels import _free

#: Distance (m) from a decision's threshold within which the rotated-frame test of
#: :func:`_rotated_blocks` defers to the exact per-heading test: its own error is below 1e-14 m
#: for neighbors within the pair reach (the module docstring), so a decision at least this far
#: from every threshold is the one the exact test takes.
MARGIN_M = 1e-7


@jit
def _exact_block(
    dx: float, dy: float, h: float, contact: float, lat: float, cap: float
) -> bool:  # pragma: no cover
    """:func:`sim.kernels.pair_blocks_along`'s test of one neighbor offset ``(dx, dy)`` against
    the heading ``h`` (rad), with the heading's ``cos`` / ``sin`` of the C library."""
    hx = math.cos(h)
    hy = math.sin(h)
    along = dx * hx + dy * hy
    if not along > 0.0:
        return False
    lateral = abs(dx * hy - dy * hx)
    if not (lateral < lat and along < cap + contact):
        return False
    if lateral >= contact:
        gap = along - contact
    else:
        gap = along - math.sqrt(max(contact * contact - lateral * lateral, 0.0))
    return max(0.0, gap) < cap


# long: the pair test in each blocked robot's frame, with the exact test near every threshold
@jit
def _rotated_blocks(
    a_all: np.ndarray,
    dx_all: np.ndarray,
    dy_all: np.ndarray,
    d2_all: np.ndarray,
    reach2: float,
    loc: np.ndarray,
    db: np.ndarray,
    c0: np.ndarray,
    s0: np.ndarray,
    offsets: np.ndarray,
    cos_off: np.ndarray,
    sin_off: np.ndarray,
    bits: np.ndarray,
    contact: float,
    lat: float,
    cap: float,
    blocked: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """The bits :func:`sim.kernels.pair_blocks_along` sets, from the unit vector ``(c0[r],
    s0[r])`` of each blocked robot's wanted heading ``db[r]`` (its ``cos`` / ``sin``, or any
    approximation of them to a few ulp): a neighbor's offset turned into that heading's frame
    (``a`` along, ``b`` across) gives its along and lateral distances for offset ``k`` as
    ``a cos(o_k) + b sin(o_k)`` and ``|a sin(o_k) - b cos(o_k)|``; the gap test ``along - sqrt(contact**2 -
    lateral**2) < cap`` is taken squared, ``(along - cap)**2 < contact**2 - lateral**2`` (where
    ``along >= cap``), so no square root is taken. Wherever one of these lies within
    :data:`MARGIN_M` of a threshold of the test (the squared gap test within ``2 contact
    MARGIN_M``: the two sides of the unsquared one are then within :data:`MARGIN_M`), the exact
    test decides (:func:`_exact_block`)."""
    kk = offsets.shape[0]
    cc = contact * contact
    lim = cap + contact
    eps = MARGIN_M
    # |d| = |t - sqrt(..)| (t + sqrt(..)) and t + sqrt(..) <= 2 contact where it matters
    eps_d = 2.0 * contact * MARGIN_M
    for p in range(a_all.shape[0]):
        if not d2_all[p] < reach2:
            continue
        r = loc[a_all[p]]
        if r < 0:
            continue
        dx = dx_all[p]
        dy = dy_all[p]
        ua = dx * c0[r] + dy * s0[r]
        ub = dy * c0[r] - dx * s0[r]
        mp = 0
        unc = 0
        for k in range(kk):
            along = ua * cos_off[k] + ub * sin_off[k]
            lateral = abs(ua * sin_off[k] - ub * cos_off[k])
            # the gap is short of the clearance when along - cap < sqrt(cc - lateral**2) (or when
            # lateral >= contact, as along < lim already says): compared squared, no square root
            t = along - cap
            d = t * t - (cc - lateral * lateral)
            hit = (
                (along > 0.0)
                & (lateral < lat)
                & (along < lim)
                & ((lateral >= contact) | (t < 0.0) | (d < 0.0))
            )
            near = (
                (abs(along) < eps)
                | (abs(lateral - lat) < eps)
                | (abs(along - lim) < eps)
                | (abs(lateral - contact) < eps)
                | (abs(d) < eps_d)
            )
            mp |= bits[k] if hit else 0
            unc |= bits[k] if near else 0
        if unc:
            for k in range(kk):
                if unc & bits[k]:
                    if _exact_block(dx, dy, db[r] + offsets[k], contact, lat, cap):
                        mp |= bits[k]
                    else:
                        mp &= ~bits[k]
        blocked[r] |= mp


# long: the pair test and the static samples of every blocked robot and offset, in one pass
@jit
def detour_blocks(
    fb: np.ndarray,
    a_all: np.ndarray,
    dx_all: np.ndarray,
    dy_all: np.ndarray,
    d2_all: np.ndarray,
    reach2: float,
    loc: np.ndarray,
    db: np.ndarray,
    xb: np.ndarray,
    yb: np.ndarray,
    c0: np.ndarray,
    s0: np.ndarray,
    offsets: np.ndarray,
    cos_off: np.ndarray,
    sin_off: np.ndarray,
    bits: np.ndarray,
    contact: float,
    lat: float,
    cap: float,
    gx: float,
    gy: float,
    res: float,
    width: int,
    height: int,
    cells: np.ndarray,
    clear_cells: np.ndarray,
    samples: np.ndarray,
    blocked: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """:func:`sim.kernels.pair_blocks` of the blocked robots ``fb`` (``a_all`` .. ``cap`` as
    there; ``cos_off``, ``sin_off``: the offsets' cosines and sines; ``c0``, ``s0``: the unit
    vectors of the wanted headings ``db``) through :func:`_rotated_blocks`, then for each blocked robot whose cell is not clear
    (``clear_cells``, the padded clearance mask; ``xb``, ``yb``: the blocked robots' positions,
    one per ``db``) and each offset its neighbors left free: the bit of the offset is set when
    a sample ``samples[j]`` m along the heading ``db[r] + offsets[k]`` (its C library ``cos`` /
    ``sin``) puts the footprint off the free cells (``cells``, the padded grid of ``width`` x
    ``height`` cells of ``res`` m from ``(gx, gy)``)."""
    nb = db.shape[0]
    kk = offsets.shape[0]
    _rotated_blocks(
        a_all,
        dx_all,
        dy_all,
        d2_all,
        reach2,
        loc,
        db,
        c0,
        s0,
        offsets,
        cos_off,
        sin_off,
        bits,
        contact,
        lat,
        cap,
        blocked,
    )
    ns = samples.shape[0]
    for r in range(nb):
        x = xb[r]
        y = yb[r]
        if _free(x, y, gx, gy, res, width, height, clear_cells):
            continue
        m = blocked[r]
        for k in range(kk):
            if m & bits[k]:
                continue
            h = db[r] + offsets[k]
            hx = math.cos(h)
            hy = math.sin(h)
            for j in range(ns):
                if not _free(x + hx * samples[j], y + hy * samples[j], gx, gy, res, width, height, cells):
                    m |= bits[k]
                    break
        blocked[r] = m


# long: the follower's corridor test, the detour search and the choice of heading, in one call
@jit
def avoid(
    fi: np.ndarray,
    desired: np.ndarray,
    rem: np.ndarray,
    side: np.ndarray,
    n: int,
    pi: np.ndarray,
    pj: np.ndarray,
    x0: np.ndarray,
    y0: np.ndarray,
    way_reach2: float,
    look: float,
    margin: float,
    tol: float,
    hx: np.ndarray,
    hy: np.ndarray,
    best: np.ndarray,
    rows: np.ndarray,
    a_all: np.ndarray,
    dx_all: np.ndarray,
    dy_all: np.ndarray,
    d2_all: np.ndarray,
    reach2: float,
    loc: np.ndarray,
    offsets: np.ndarray,
    cos_off: np.ndarray,
    sin_off: np.ndarray,
    bits: np.ndarray,
    first_free: np.ndarray,
    contact: float,
    lat: float,
    cap: float,
    gx: float,
    gy: float,
    res: float,
    width: int,
    height: int,
    cells: np.ndarray,
    clear_cells: np.ndarray,
    samples: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """``PathFollower._avoid`` without dynamic obstacles, in one call: the follower's corridor
    test (:func:`sim.follower_kernels.way_blocked`, arguments ``fi`` .. ``rows`` with
    ``contact``, ``lat``, and ``look`` its lookahead) finds the blocked robots; their blocked
    detour headings come from :func:`detour_blocks` (arguments ``a_all`` .. ``samples`` as
    there; the robots' positions ``x``, ``y``);
    each blocked robot ``fi[q]`` with a free heading turns ``desired[q]`` by the first free
    offset of ``first_free[side[q] + 1, mask]`` (``Avoidance.detour``'s table) and takes its
    side (+1 left, -1 right); without one it keeps both. ``loc`` (-1 for every robot, left
    so) is scratch by robot. Returns the number of blocked robots (their ``q`` in ``rows``)."""
    nb = way_blocked(
        fi,
        desired,
        rem,
        side,
        n,
        pi,
        pj,
        x0,
        y0,
        way_reach2,
        contact,
        lat,
        look,
        margin,
        tol,
        hx,
        hy,
        best,
        rows,
    )
    if nb == 0:
        return 0
    fb = np.empty(nb, dtype=np.int64)
    db = np.empty(nb)
    xb = np.empty(nb)
    yb = np.empty(nb)
    c0 = np.empty(nb)
    s0 = np.empty(nb)
    for r in range(nb):
        i = fi[rows[r]]
        fb[r] = i
        db[r] = desired[rows[r]]
        xb[r] = x[i]
        yb[r] = y[i]
        c0[r] = hx[i]  # the corridor test's unit vector of the same heading
        s0[r] = hy[i]
        loc[i] = r
    blocked = np.zeros(nb, dtype=np.int64)
    detour_blocks(
        fb, a_all, dx_all, dy_all, d2_all, reach2, loc, db, xb, yb, c0, s0, offsets, cos_off, sin_off, bits, contact,
        lat, cap, gx, gy, res, width, height, cells, clear_cells, samples, blocked,
    )  # fmt: skip
    for r in range(nb):
        q = rows[r]
        loc[fb[r]] = -1
        k = first_free[side[q] + 1, blocked[r]]
        if k >= 0:
            desired[q] = db[r] + offsets[k]
            side[q] = 1 if offsets[k] > 0 else -1
    return nb


def warm_up() -> None:
    """Compile (or load from the cache) :func:`detour_blocks` with the detour's argument types."""
    ints = np.zeros(0, dtype=np.int64)
    f = np.zeros(0)
    cells = np.zeros(9, dtype=bool)
    detour_blocks(
        ints, ints, f, f, f, 1.0, ints, f, f, f, f, f, np.zeros(1), np.ones(1), np.zeros(1),
        np.ones(1, dtype=np.int64), 0.6, 0.65, 0.8, 0.0, 0.0, 0.1, 1, 1, cells, cells, np.zeros(1), ints,
    )  # fmt: skip
    avoid(
        ints, f, f, ints, 0, ints, ints, f, f, 1.0, 1.5, 0.6, 0.1, f, f, f, ints, ints, f, f, f, 1.0, ints,
        np.zeros(1), np.ones(1), np.zeros(1), np.ones(1, dtype=np.int64), np.zeros((3, 2), dtype=np.int64),
        0.6, 0.65, 0.8, 0.0, 0.0, 0.1, 1, 1, cells, cells, np.zeros(1), f, f,
    )  # fmt: skip


register_warm_up(warm_up)
