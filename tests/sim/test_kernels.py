"""The compiled kernels compute the very floats of the NumPy expressions they replaced."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from sim import kernels
from sim.avoidance import AVOID_CLEAR_M, CORRIDOR_MARGIN_M, OFFSETS


def _gaps(along: np.ndarray, lateral: np.ndarray, contact: float) -> np.ndarray:
    inner = along - np.sqrt(np.maximum(contact * contact - lateral * lateral, 0.0))
    return np.maximum(0.0, np.where(lateral >= contact, along - contact, inner))


def _scene(seed: int, n: int, span: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Directed pairs of ``n`` robots scattered over ``span`` m (every ordered pair)."""
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(0.0, span, n), rng.uniform(0.0, span, n)
    i, j = np.nonzero(~np.eye(n, dtype=bool))
    dx, dy = x[j] - x[i], y[j] - y[i]
    return i.astype(np.int64), dx, dy, dx * dx + dy * dy


def _pair_blocks_numpy(
    a_all: np.ndarray, dx_all: np.ndarray, dy_all: np.ndarray, d2_all: np.ndarray, reach: float,
    loc: np.ndarray, db: np.ndarray, contact: float, lat: float, nb: int,
) -> np.ndarray:  # fmt: skip
    """The exact corridor test of every (pair, offset) as whole-array NumPy."""
    sel = np.flatnonzero((d2_all < reach * reach) & (loc[a_all] >= 0))
    a, dx, dy = loc[a_all[sel]], dx_all[sel], dy_all[sel]
    kk = OFFSETS.size
    p = np.repeat(np.arange(a.size), kk)
    k = np.tile(np.arange(kk), a.size)
    h = db[a[p]] + OFFSETS[k]
    hx, hy = np.cos(h), np.sin(h)
    along = dx[p] * hx + dy[p] * hy
    lateral = np.abs(dx[p] * hy - dy[p] * hx)
    hit = np.flatnonzero((along > 0.0) & (lateral < lat) & (along < AVOID_CLEAR_M + contact))
    bad = hit[_gaps(along[hit], lateral[hit], contact) < AVOID_CLEAR_M]
    out = np.zeros(nb, dtype=np.int64)
    np.bitwise_or.at(out, a[p[bad]], np.left_shift(1, k[bad]))
    return out


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(2, 60),
    span=st.floats(0.5, 6.0),
    radius=st.floats(0.1, 0.4),
)
def test_pair_blocks_is_the_exact_corridor_test(seed: int, n: int, span: float, radius: float) -> None:
    a_all, dx, dy, d2 = _scene(seed, n, span)
    rng = np.random.default_rng(seed + 1)
    contact = 2.0 * radius
    lat = contact + CORRIDOR_MARGIN_M
    reach = math.hypot(AVOID_CLEAR_M + contact, lat)
    fb = np.flatnonzero(rng.random(n) < 0.7)
    loc = np.full(n, -1, dtype=np.int64)
    loc[fb] = np.arange(fb.size)
    db = rng.uniform(-math.pi, math.pi, fb.size)
    got = np.zeros(fb.size, dtype=np.int64)
    bits = np.left_shift(1, np.arange(OFFSETS.size, dtype=np.int64))
    kernels.pair_blocks(
        a_all, dx, dy, d2, reach * reach, loc, db, OFFSETS, bits, contact, lat, AVOID_CLEAR_M, got
    )
    want = _pair_blocks_numpy(a_all, dx, dy, d2, reach, loc, db, contact, lat, fb.size)
    assert got.tolist() == want.tolist()


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 60), span=st.floats(0.5, 8.0))
def test_corridor_min_is_the_numpy_minimum(seed: int, n: int, span: float) -> None:
    a, dx, dy, _ = _scene(seed, n, span)
    rng = np.random.default_rng(seed + 2)
    th = rng.uniform(-math.pi, math.pi, n)
    moving = rng.random(n) < 0.8  # the others have heading (0, 0), as corridor_free gives them
    hx, hy = np.where(moving, np.cos(th), 0.0), np.where(moving, np.sin(th), 0.0)
    cap = rng.uniform(0.1, 2.0, n)
    contact, lat = 0.6, 0.65
    got = cap.copy()
    kernels.corridor_min(a, dx, dy, dx * dx + dy * dy, math.inf, hx, hy, cap, contact, lat, got)
    want = cap.copy()
    along = dx * hx[a] + dy * hy[a]
    lateral = np.abs(dx * hy[a] - dy * hx[a])
    hit = np.flatnonzero((along > 0.0) & (lateral < lat) & (along < cap[a] + contact))
    np.minimum.at(want, a[hit], _gaps(along[hit], lateral[hit], contact))
    assert got.tobytes() == want.tobytes()


def test_libm_trigonometry_matches_numpy() -> None:
    """The kernels' ``math.cos`` / ``math.sin`` / ``math.sqrt`` give NumPy's bits here (what
    bit-identical results rest on)."""
    x = np.random.default_rng(7).uniform(-20.0, 20.0, 200_000)
    assert np.cos(x).tobytes() == np.array([math.cos(v) for v in x.tolist()]).tobytes()
    assert np.sin(x).tobytes() == np.array([math.sin(v) for v in x.tolist()]).tobytes()
    ax = np.abs(x)
    assert np.sqrt(ax).tobytes() == np.array([math.sqrt(v) for v in ax.tolist()]).tobytes()
