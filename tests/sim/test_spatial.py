"""The charger test of the battery step (:func:`sim.spatial.near_any`) gives the answer of the
all-pairs expression it replaced, bit for bit, on points placed at and around the radius."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from sim.spatial import near_any


def _all_pairs(px: np.ndarray, py: np.ndarray, sx: np.ndarray, sy: np.ndarray, r: float) -> np.ndarray:
    if sx.shape[0] == 0:
        return np.zeros(px.shape[0], dtype=bool)
    near = np.hypot(sx[None, :] - px[:, None], sy[None, :] - py[:, None])
    out: np.ndarray = (near <= r).any(axis=1)
    return out


@settings(max_examples=200, deadline=None)
@given(
    st.integers(min_value=0, max_value=2**32 - 1),
    st.integers(min_value=0, max_value=60),
    st.integers(min_value=0, max_value=30),
    st.floats(min_value=0.05, max_value=3.0),
)
def test_near_any_is_the_all_pairs_test(seed: int, n: int, m: int, radius: float) -> None:
    rng = np.random.default_rng(seed)
    sx = np.round(rng.uniform(0.0, 20.0, m), 1)  # sites on a coarse grid: equal x values
    sy = np.round(rng.uniform(0.0, 5.0, m), 1)
    pick = rng.integers(0, max(m, 1), n)
    ang = rng.uniform(0.0, 2 * np.pi, n)
    # half the points exactly on or within a hair of the radius around a site, half anywhere
    dist = radius * rng.choice([1.0, 1.0 - 1e-12, 1.0 + 1e-12, 0.5, 2.0], n)
    near = rng.random(n) < 0.5
    px = np.where(near & (m > 0), (sx[pick] if m else 0.0) + dist * np.cos(ang), rng.uniform(-2.0, 22.0, n))
    py = np.where(near & (m > 0), (sy[pick] if m else 0.0) + dist * np.sin(ang), rng.uniform(-2.0, 7.0, n))
    assert np.array_equal(near_any(px, py, sx, sy, radius), _all_pairs(px, py, sx, sy, radius))


def test_no_points_or_no_sites() -> None:
    empty = np.zeros(0)
    assert near_any(empty, empty, np.ones(3), np.ones(3), 1.0).shape == (0,)
    assert not near_any(np.ones(2), np.ones(2), empty, empty, 1.0).any()
