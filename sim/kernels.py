"""Compiled kernels of the simulator's step (numba): loops over robots and neighbor pairs that
NumPy can only do as many whole-array passes, and the switch that chooses them.

Each kernel computes exactly what the NumPy code it replaces computes, with the same
floating-point operations in the same order on the same values: plain IEEE double arithmetic,
no fast-math (no fused multiply-add, no reassociation), ``math.cos`` / ``math.sin`` /
``math.sqrt`` / ``math.hypot`` (the C library's, which on the project's machines give the very
bits NumPy's give; ``tests/sim/test_kernels.py`` checks them), and NumPy's own rule for
``minimum`` / ``maximum`` (the second operand when they compare equal, which decides the sign
of a zero). ``arctan2`` is the exception: NumPy's vectorized one differs from the C library's
in the last bit for about 8 % of inputs here, so the follower calls NumPy's between two
kernels.

**Compiled or NumPy.** numba is a dependency of the project (``make setup`` installs it), but
the simulator runs without it: :func:`enabled` tells whether the compiled kernels are used
(numba importable and ``FLEET_SIM_KERNELS`` not set to ``numpy``); otherwise every stage runs
its NumPy code, with bit-identical results (``tests/sim/test_kernels.py`` runs a fleet both
ways and compares every state). Kernels are compiled on first use and cached next to this
module (``cache=True``, in ``__pycache__``); :func:`ready` compiles them all (or loads them
from the cache) once per process when the first simulator is made, so no step pays for it, and
turns them off with a warning if they cannot compile here.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable
from types import ModuleType
from typing import Any, TypeVar, cast

import numpy as np

_numba: ModuleType | None
try:
    import numba as _numba
except ImportError:  # pragma: no cover - the NumPy code runs instead
    _numba = None

#: Set to ``numpy`` to run the simulator's NumPy code even where numba is installed.
ENV_VAR = "FLEET_SIM_KERNELS"

log = logging.getLogger(__name__)
#: Whether every kernel compiled (or loaded from the cache) in this process; None: not tried.
_ready: bool | None = None
#: The warm-ups :func:`ready` runs: this module's and those the other kernel modules register.
_warm_ups: list[Callable[[], None]] = []


def register_warm_up(fn: Callable[[], None]) -> None:
    """Have :func:`ready` run ``fn`` (a kernel module's warm-up, which calls its kernels with
    the simulator's argument types on empty inputs)."""
    _warm_ups.append(fn)


_F = TypeVar("_F", bound=Callable[..., Any])


def available() -> bool:
    """Whether numba is installed, so the kernels can be compiled."""
    return _numba is not None


def enabled() -> bool:
    """Whether a simulator built now uses the compiled kernels: numba is installed,
    ``FLEET_SIM_KERNELS`` is not ``numpy`` and the kernels compile here (:func:`ready`)."""
    return available() and os.environ.get(ENV_VAR, "").strip().lower() != "numpy" and ready()


def ready() -> bool:
    """Compile every kernel of the simulator (or load it from the cache) once per process, so
    no step pays for it; False, with a warning, when that fails (numba installed but unable to
    compile here): the simulator then runs its NumPy code."""
    global _ready
    if _ready is None:
        if _numba is None:  # pragma: no cover
            _ready = False
            return False
        try:
            for fn in _warm_ups:
                fn()
            _ready = True
        except Exception as exc:  # e.g. a broken llvmlite: the NumPy code gives the same run
            log.warning(
                "the simulator's compiled kernels are not available (%s); running its NumPy code", exc
            )
            _ready = False
    return _ready


def jit(fn: _F) -> _F:
    """Compile ``fn`` with numba (no-Python mode, cached, releasing the GIL) where numba is
    installed; without numba ``fn`` stays a plain Python function (never called by the
    simulator then: it runs its NumPy code)."""
    if _numba is None:  # pragma: no cover
        return fn
    return cast(_F, _numba.njit(cache=True, nogil=True)(fn))


@jit
def pair_blocks(
    a_all: np.ndarray,
    dx_all: np.ndarray,
    dy_all: np.ndarray,
    d2_all: np.ndarray,
    reach2: float,
    loc: np.ndarray,
    db: np.ndarray,
    offsets: np.ndarray,
    bits: np.ndarray,
    contact: float,
    lat: float,
    cap: float,
    blocked: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """The detour headings each robot's neighbors block, by the exact corridor test.

    For every directed pair ``p`` (robot ``a_all[p]``, neighbor at offset ``dx_all[p]``,
    ``dy_all[p]``, squared distance ``d2_all[p]``) with ``d2 < reach2`` whose robot is blocked
    (``loc[robot] >= 0``, its row in ``db``), and every detour offset ``k``: the heading
    ``db[r] + offsets[k]`` is blocked when the neighbor is ahead (``along > 0``), inside the
    corridor (``lateral < lat``), closer than ``cap + contact`` along it, and the robot's
    disc would touch it within ``cap``; then ``bits[k]`` is or-ed into ``blocked[r]``."""
    hx, hy = detour_headings(db, offsets)
    pair_blocks_along(a_all, dx_all, dy_all, d2_all, reach2, loc, hx, hy, bits, contact, lat, cap, blocked)


@jit
def detour_headings(db: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover
    """The unit vectors ``(cos, sin)`` of every heading ``db[r] + offsets[k]`` (rows ``r``,
    columns ``k``): the C library's values, which NumPy's ``cos``/``sin`` also give."""
    nb = db.shape[0]
    kk = offsets.shape[0]
    hx = np.empty((nb, kk))
    hy = np.empty((nb, kk))
    for r in range(nb):
        for k in range(kk):
            h = db[r] + offsets[k]
            hx[r, k] = math.cos(h)
            hy[r, k] = math.sin(h)
    return hx, hy


@jit
def pair_blocks_along(
    a_all: np.ndarray,
    dx_all: np.ndarray,
    dy_all: np.ndarray,
    d2_all: np.ndarray,
    reach2: float,
    loc: np.ndarray,
    hx: np.ndarray,
    hy: np.ndarray,
    bits: np.ndarray,
    contact: float,
    lat: float,
    cap: float,
    blocked: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """:func:`pair_blocks` on headings already turned into unit vectors
    (:func:`detour_headings`)."""
    kk = hx.shape[1]
    cc = contact * contact
    lim = cap + contact
    for p in range(a_all.shape[0]):
        if not d2_all[p] < reach2:
            continue
        r = loc[a_all[p]]
        if r < 0:
            continue
        dx = dx_all[p]
        dy = dy_all[p]
        m = blocked[r]
        for k in range(kk):
            along = dx * hx[r, k] + dy * hy[r, k]
            if not along > 0.0:
                continue
            lateral = abs(dx * hy[r, k] - dy * hx[r, k])
            if not (lateral < lat and along < lim):
                continue
            if lateral >= contact:
                gap = along - contact
            else:
                gap = along - math.sqrt(max(cc - lateral * lateral, 0.0))
            if max(0.0, gap) < cap:
                m |= bits[k]
        blocked[r] = m


@jit
def corridor_min(
    a: np.ndarray,
    dx: np.ndarray,
    dy: np.ndarray,
    d2: np.ndarray,
    reach2: float,
    hx: np.ndarray,
    hy: np.ndarray,
    cap: np.ndarray,
    contact: float,
    lat: float,
    best: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Lower ``best[i]`` to the corridor gap of every pair ``(i = a[p], offset dx[p], dy[p])``
    with ``d2[p] < reach2`` whose neighbor is ahead along ``(hx[i], hy[i])``, inside the
    corridor and closer than ``cap[i] + contact`` (what ``np.minimum.at`` does in
    :func:`sim.avoidance.corridor_min_numpy`). A pair the reach leaves out cannot be in the
    corridor when ``reach2 >= max(cap + contact)**2 + lat**2``."""
    cc = contact * contact
    inf = math.inf
    # branch-free (see follower_kernels.way_blocked): the gap of every pair, kept where it counts
    for p in range(a.shape[0]):
        i = a[p]
        hxa = hx[i]
        hya = hy[i]
        along = dx[p] * hxa + dy[p] * hya
        lateral = abs(dx[p] * hya - dy[p] * hxa)
        hit = (d2[p] < reach2) & (along > 0.0) & (lateral < lat) & (along < cap[i] + contact)
        gap = along - contact if lateral >= contact else along - math.sqrt(max(cc - lateral * lateral, 0.0))
        g = max(0.0, gap) if hit else inf
        b = best[i]
        best[i] = g if g < b else b


def warm_up() -> None:
    """Compile (or load from the cache) every kernel with the argument types the simulator
    passes, on empty inputs."""
    ints = np.zeros(0, dtype=np.int64)
    floats = np.zeros(0)
    pair_blocks(
        ints,
        floats,
        floats,
        floats,
        1.0,
        ints,
        floats,
        np.zeros(1),
        np.ones(1, dtype=np.int64),
        0.6,
        0.65,
        0.8,
        ints,
    )
    corridor_min(ints, floats, floats, floats, 1.0, floats, floats, floats, 0.6, 0.65, floats)


@jit
def cell_pairs(
    order: np.ndarray,
    pos_hi: np.ndarray,
    lo2: np.ndarray,
    hi2: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    r2: float,
    a: np.ndarray,
    b: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """The candidate pairs of :func:`sim.spatial.neighbor_pairs` closer than ``sqrt(r2)``, in
    its order: for every sorted position ``p`` the points ``p + 1 .. pos_hi[p] - 1`` (its
    cell and the next), then for every ``p`` the points ``lo2[p] .. hi2[p] - 1`` (the row
    above); ``i = order[p]``, ``j = order[q]``, kept when ``dx * dx + dy * dy < r2`` with
    ``dx = x[j] - x[i]``. Writes the kept pairs to ``a``, ``b``; returns how many."""
    k = 0
    n = order.shape[0]
    for p in range(n):
        i = order[p]
        for q in range(p + 1, pos_hi[p]):
            j = order[q]
            dx = x[j] - x[i]
            dy = y[j] - y[i]
            a[k] = i  # branch-free: written at k, kept when k moves on (k < the candidates seen)
            b[k] = j
            k += dx * dx + dy * dy < r2
    for p in range(n):
        i = order[p]
        for q in range(lo2[p], hi2[p]):
            j = order[q]
            dx = x[j] - x[i]
            dy = y[j] - y[i]
            a[k] = i  # branch-free: written at k, kept when k moves on (k < the candidates seen)
            b[k] = j
            k += dx * dx + dy * dy < r2
    return k


@jit
def short_pairs(
    pi: np.ndarray,
    pj: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    short2: float,
    si: np.ndarray,
    sj: np.ndarray,
    sdx: np.ndarray,
    sdy: np.ndarray,
    sd2: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """The pairs ``(pi[p], pj[p])`` closer than ``sqrt(short2)``, in order, into ``si``,
    ``sj`` with their offsets ``sdx = x[pj] - x[pi]``, ``sdy``, ``sd2 = sdx * sdx + sdy *
    sdy`` (NumPy's floats for the same expressions); returns how many."""
    k = 0
    for p in range(pi.shape[0]):
        a = pi[p]
        b = pj[p]
        ex = x[b] - x[a]
        ey = y[b] - y[a]
        e2 = ex * ex + ey * ey
        # branch-free: every pair is written at k, and k moves on past the kept ones (k <= p)
        si[k] = a
        sj[k] = b
        sdx[k] = ex
        sdy[k] = ey
        sd2[k] = e2
        k += e2 < short2
    return k


@jit
def touching_pairs(
    pa: np.ndarray,
    pb: np.ndarray,
    pd2: np.ndarray,
    before2: float,
    x: np.ndarray,
    y: np.ndarray,
    contact: float,
    ta: np.ndarray,
    tb: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """The pairs ``(pa[p], pb[p])`` with ``pa < pb`` that were closer than ``sqrt(before2)``
    at the step's start (``pd2``) and whose centers at ``x``, ``y`` are now closer than
    ``contact`` (``hypot``, NumPy's bits), in order, into ``ta``, ``tb``; returns how many
    (what :meth:`sim.safety.Contacts.count` computes with NumPy)."""
    k = 0
    for p in range(pa.shape[0]):
        a = pa[p]
        b = pb[p]
        if a < b and pd2[p] < before2 and math.hypot(x[b] - x[a], y[b] - y[a]) < contact:
            ta[k] = a
            tb[k] = b
            k += 1
    return k


def warm_up_pairs() -> None:
    """Compile (or load from the cache) :func:`cell_pairs` and :func:`short_pairs`."""
    ints = np.zeros(0, dtype=np.int64)
    floats = np.zeros(0)
    cell_pairs(ints, ints, ints, ints, floats, floats, 1.0, ints, ints)
    short_pairs(ints, ints, floats, floats, 1.0, ints, ints, floats, floats, floats)
    touching_pairs(ints, ints, floats, 1.0, floats, floats, 0.6, ints, ints)


register_warm_up(warm_up)
register_warm_up(warm_up_pairs)
