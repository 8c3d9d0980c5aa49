"""Neighbourhoods against brute-force all-pairs distances."""

import numpy as np
import pytest

import hgjax
from hgjax.neighbourhoods import SpatialIndex

from naive import knn_rows, resolution


def cloud(n=300, seed=0):
    return np.random.default_rng(seed).random((n, 3))


def test_knn_matches_brute_force():
    p = cloud()
    nb = hgjax.knn(p, 10)
    assert nb.idx.dtype == np.int32 and nb.idx.shape == (300, 10)
    np.testing.assert_array_equal(nb.idx, knn_rows(p, 10))


def test_knn_self_first_with_duplicates():
    p = np.repeat(cloud(20), 5, axis=0)  # every point 5 times
    nb = hgjax.knn(p, 3)  # fewer columns than duplicates
    np.testing.assert_array_equal(nb.idx[:, 0], np.arange(100))
    assert (np.linalg.norm(p[nb.idx] - p[:, None], axis=-1) == 0).all()


def test_cube_matches_brute_force_and_grows_capacity():
    p = cloud(400)
    h = 0.12
    nb = hgjax.cube(p, h, capacity=1)  # forces several doublings
    cheb = np.abs(p[:, None] - p[None]).max(-1)
    want = [set(np.flatnonzero(row <= h)) for row in cheb]
    got = [set(r[r < len(p)].tolist()) for r in nb.idx]
    assert got == want
    assert nb.idx.shape[1] >= max(len(w) for w in want)


def test_cube_overflow_raises_past_max_capacity():
    p = np.zeros((50, 3))
    with pytest.raises(ValueError, match="max_capacity"):
        hgjax.cube(p, 1.0, capacity=4, max_capacity=16)


def test_neighbourhoods_do_not_depend_on_input_order():
    p = cloud(200)
    perm = np.random.default_rng(1).permutation(200)
    a, b = hgjax.knn(p, 8).idx, hgjax.knn(p[perm], 8).idx
    np.testing.assert_array_equal(perm[b], a[perm])


def test_intrinsic_resolution_small_is_exact_and_large_is_deterministic():
    p = cloud(500)
    assert hgjax.intrinsic_resolution(p) == pytest.approx(resolution(p), rel=1e-12)
    big = cloud(5000, seed=3)
    r = hgjax.intrinsic_resolution(big)
    perm = np.random.default_rng(2).permutation(5000)
    assert hgjax.intrinsic_resolution(big[perm]) == r  # same subset whatever the order
    assert r == pytest.approx(resolution(big[:2000]) * np.sqrt(2000 / 5000), rel=0.2)


def test_intrinsic_resolution_all_equal_is_zero():
    assert hgjax.intrinsic_resolution(np.ones((10, 3))) == 0.0


def test_spatial_index_chunks_cover_rows():
    index = SpatialIndex(cloud(103))
    rows = np.concatenate([np.arange(s.start, s.stop) for s in index.chunks(10)])
    np.testing.assert_array_equal(rows, np.arange(103))


def test_spatial_order_breaks_shared_cells_by_coordinates():
    # Two far-apart points stretch the grid, so the 300 points near the origin share a
    # handful of Morton cells and the coordinate tie-break decides their order.
    p = np.concatenate([cloud(300) * 1e-9, [[1.0, 1.0, 1.0], [-1.0, 0.5, 0.0]]])
    order = hgjax.spatial_order(p)
    np.testing.assert_array_equal(np.sort(order), np.arange(len(p)))
    perm = np.random.default_rng(4).permutation(len(p))
    np.testing.assert_array_equal(p[perm][hgjax.spatial_order(p[perm])], p[order])
    tied = p[order][1:-1]  # the near-origin points, between the two far ones in Z order
    assert (np.diff(tied[:, 0]) >= 0).all()  # one cell here: sorted by x
