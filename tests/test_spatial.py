"""hgjax.neighbours.spatial: neighbourhoods against brute-force all-pairs distances."""

import warnings

import jax
import numpy as np
import pytest

import hgjax
from hgjax.neighbours.spatial import SpatialIndex

from fixtures import grid, uniform_cloud
from naive import knn_rows, resolution


def chebyshev(p):
    return np.abs(p[:, None] - p[None]).max(-1)


def row_sets(idx, n):
    return [set(r[r < n].tolist()) for r in np.asarray(idx)]


def with_duplicates(n=120, seed=0):
    """A cloud whose rows 0..n-1 are distinct and the rest copies of some of them, shuffled."""
    base = uniform_cloud(n, seed)
    p = np.concatenate([base, base[:40], base[:40], base[10:15]])
    return p[np.random.default_rng(seed + 1).permutation(len(p))]


def first_copies(p):
    """(first, inverse): caller index of each location's first copy, and each point's location."""
    _, first, inverse = np.unique(p, axis=0, return_index=True, return_inverse=True)
    return first, inverse.ravel()


# ---------------------------------------------------------------- knn
def test_knn_matches_brute_force():
    p = uniform_cloud(300)
    nb = hgjax.knn(p, 10)
    assert isinstance(nb, hgjax.Neighbourhoods)
    assert nb.idx.dtype == np.int32 and nb.idx.shape == (300, 10) and nb.scale is None
    np.testing.assert_array_equal(nb.idx, knn_rows(p, 10))


def test_knn_capacity_pads_with_the_sentinel():
    p = uniform_cloud(50)
    nb = hgjax.knn(p, 5, capacity=8)
    assert nb.idx.shape == (50, 8)
    np.testing.assert_array_equal(nb.idx[:, :5], knn_rows(p, 5))
    assert (nb.idx[:, 5:] == 50).all() and nb.mask[:, :5].all() and not nb.mask[:, 5:].any()
    with pytest.raises(ValueError, match="capacity"):
        hgjax.knn(p, 5, capacity=4)


def test_knn_self_first_with_duplicates():
    p = np.repeat(uniform_cloud(20), 5, axis=0)  # every point 5 times
    nb = hgjax.knn(p, 3)  # fewer columns than duplicates
    np.testing.assert_array_equal(nb.idx[:, 0], np.arange(100))
    assert (np.linalg.norm(p[nb.idx] - p[:, None], axis=-1) == 0).all()


def test_knn_dedupe_gives_every_copy_its_first_copys_neighbourhood():
    p = with_duplicates()
    first, inverse = first_copies(p)
    nb = hgjax.knn(p, 8, dedupe=True)
    # brute force on the distinct locations, mapped to their first copies
    want = first[knn_rows(p[first], 8)][inverse]
    np.testing.assert_array_equal(nb.idx, want)
    np.testing.assert_array_equal(nb.idx[:, 0], first[inverse])  # the first copy, not the point
    for row in nb.idx:  # no row lists two copies of one location
        assert len(np.unique(p[row], axis=0)) == len(row)


def test_knn_dedupe_pads_when_too_few_distinct_locations():
    p = np.repeat(uniform_cloud(4), 3, axis=0)  # 12 points, 4 locations
    nb = hgjax.knn(p, 6, dedupe=True)
    assert (nb.mask.sum(axis=1) == 4).all() and (nb.idx[:, 4:] == 12).all()


# ---------------------------------------------------------------- cube
def test_cube_matches_brute_force():
    p = uniform_cloud(400)
    h = 0.12
    nb = hgjax.cube(p, h)
    want = [set(np.flatnonzero(row < h)) for row in chebyshev(p)]
    assert row_sets(nb.idx, len(p)) == want
    width = max(len(w) for w in want)
    assert nb.idx.shape[1] == max(8, 1 << (width - 1).bit_length())  # the next power of two
    np.testing.assert_array_equal(nb.idx[:, 0], np.arange(400))  # the point itself first
    cheb = chebyshev(p)
    for i, row in enumerate(nb.idx):  # by increasing Chebyshev distance
        assert (np.diff(cheb[i, row[row < len(p)]]) >= 0).all()


def test_cube_per_point_half_widths_match_brute_force():
    p = uniform_cloud(300, seed=5)
    h = np.random.default_rng(6).uniform(0.02, 0.2, len(p))
    nb = hgjax.cube(p, h)
    want = [set(np.flatnonzero(row < hi)) for row, hi in zip(chebyshev(p), h)]
    assert row_sets(nb.idx, len(p)) == want
    with pytest.raises(ValueError, match="half_width"):
        hgjax.cube(p, h[:10])


def test_cube_rows_widen_when_a_later_query_batch_is_wider():
    # three query batches in spatial order: the first's cubes hold a few points, the later ones' about 70
    from scipy.spatial import cKDTree
    p = uniform_cloud(40_000, seed=2)
    order = SpatialIndex(hgjax.neighbours.spatial.local_frame(p)[0]).order
    h = np.full(len(p), 0.06)
    h[order[:hgjax.neighbours.spatial.QUERY_ROWS]] = 0.01
    nb = hgjax.cube(p, h)
    tree = cKDTree(p)
    want = [set(tree.query_ball_point(x, hi, p=np.inf)) for x, hi in zip(p, h)]
    assert row_sets(nb.idx, len(p)) == want
    first = max(len(want[i]) for i in order[:hgjax.neighbours.spatial.QUERY_ROWS])
    width = max(len(w) for w in want)
    assert hgjax.neighbours.spatial.bucket(first) < nb.idx.shape[1] == hgjax.neighbours.spatial.bucket(width)
    with pytest.raises(ValueError, match=rf"capacity={first} is too small.*holds {width} points"):
        hgjax.cube(p, h, capacity=first)  # the widest row is named, not the first one over


def test_spatial_index_cube_grows_its_capacity():
    p = uniform_cloud(400)
    index = SpatialIndex(p)
    idx, half = index.cube(0.12, capacity=1)  # forces several doublings
    want = [set(np.flatnonzero(row < 0.12)) for row in chebyshev(index.points)]
    assert row_sets(idx, len(p)) == want
    assert idx.shape[1] == max(len(w) for w in want)
    np.testing.assert_array_equal(half, 0.12)


def test_cube_fixed_capacity_too_small_names_the_capacity_needed():
    p = np.zeros((50, 3))
    with pytest.raises(ValueError, match=r"capacity=4 is too small.*holds 50 points.*capacity >= 50"):
        hgjax.cube(p, 1.0, capacity=4)
    assert hgjax.cube(p, 1.0, capacity=64).idx.shape == (50, 64)


def test_cube_dedupe_gives_every_copy_its_first_copys_neighbourhood():
    p = with_duplicates(seed=3)
    first, inverse = first_copies(p)
    nb = hgjax.cube(p, 0.15, dedupe=True)
    distinct = [set(first[np.flatnonzero(row < 0.15)].tolist()) for row in chebyshev(p[first])]
    assert row_sets(nb.idx, len(p)) == [distinct[j] for j in inverse]
    np.testing.assert_array_equal(nb.idx[:, 0], first[inverse])


def test_max_count_shrinks_cubes_without_dropping_points_inside():
    # a dense cluster next to a sparse grid: the sparse points near it see too many points
    rng = np.random.default_rng(7)
    p = np.concatenate([rng.random((400, 3)) * 0.05, rng.random((100, 3))])
    index = SpatialIndex(p)
    full, h_full = index.cube(0.1)
    shrunk, h = index.cube(0.1, max_count=32, capacity=4)
    counts = (shrunk < index.n).sum(axis=1)
    assert counts.max() < 32 and (h <= 0.1).all() and (h < 0.1).any()
    cheb = chebyshev(index.points)
    assert row_sets(shrunk, index.n) == [set(np.flatnonzero(row < hi)) for row, hi in zip(cheb, h)]
    small = (full < index.n).sum(axis=1) < 32  # cubes that already held fewer keep their width
    np.testing.assert_array_equal(h[small], 0.1)
    np.testing.assert_array_equal(h_full, 0.1)
    grow = h < 0.1  # a shrunk cube is as large as it can be: its boundary point has count 32
    assert ((cheb[grow] <= h[grow, None]).sum(axis=1) >= 32).all()


# ---------------------------------------------------------------- order, frame, resolution
@pytest.mark.parametrize("build", [lambda p: hgjax.knn(p, 8), lambda p: hgjax.cube(p, 0.1)], ids=["knn", "cube"])
def test_neighbourhoods_do_not_depend_on_input_order(build):
    p = uniform_cloud(200)
    perm = np.random.default_rng(1).permutation(200)
    a, b = build(p).idx, build(p[perm]).idx
    np.testing.assert_array_equal(np.where(b < 200, perm[np.minimum(b, 199)], 200), a[perm])


def test_local_frame_is_exact():
    rng = np.random.default_rng(8)
    offset = np.array([512345.0, 4123456.0, 210.0])  # UTM-like
    p64 = offset + rng.random((500, 3)) * [30.0, 20.0, 5.0]
    local, origin = hgjax.local_frame(p64)
    assert local.dtype == np.float64 and origin.dtype == np.float64
    np.testing.assert_array_equal(origin, (p64.min(0) + p64.max(0)) / 2)
    np.testing.assert_array_equal(local, p64 - origin)
    np.testing.assert_allclose(local.min(0), -local.max(0), rtol=1e-10)  # centred on the bounding box
    p32 = p64.astype(np.float32)
    local32, origin32 = hgjax.local_frame(p32)
    np.testing.assert_array_equal(local32 + origin32, p32.astype(np.float64))  # float32 input: exact
    np.testing.assert_array_equal(local32.min(0), -local32.max(0))
    # Neighbourhoods carry the local frame, cast only afterwards: millimetres survive float32
    nb = hgjax.knn(p64.astype(np.float64), 8)
    np.testing.assert_array_equal(nb.points, local)
    nb32 = hgjax.knn(p32, 8)
    assert nb32.points.dtype == np.float32
    np.testing.assert_array_equal(nb32.points, local32.astype(np.float32))
    # float64 input without x64: the local frame is taken in float64, then cast; float32's rounding
    # in that frame (about 5e-7 at 15 m) is small against the spacing, so no PrecisionWarning
    jax.config.update("jax_enable_x64", False)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", hgjax.PrecisionWarning)
            cast = hgjax.knn(p64, 8)
    finally:
        jax.config.update("jax_enable_x64", True)
    np.testing.assert_array_equal(cast.points, local.astype(np.float32))
    assert np.abs(cast.points - local).max() < 1e-5  # raw UTM in float32 would be off by up to 0.25
    np.testing.assert_array_equal(hgjax.knn(p64 - origin, 8).idx, nb.idx)  # translation: same rows


def test_intrinsic_resolution_small_is_exact_and_large_is_deterministic():
    p = uniform_cloud(500)
    assert hgjax.intrinsic_resolution(p) == pytest.approx(resolution(p), rel=1e-12)
    big = uniform_cloud(5000, seed=3)
    r = hgjax.intrinsic_resolution(big)
    perm = np.random.default_rng(2).permutation(5000)
    assert hgjax.intrinsic_resolution(big) == r  # a seeded sample of global ids: deterministic
    assert hgjax.intrinsic_resolution(big[perm]) == pytest.approx(r, rel=0.1)  # another sample, same scale
    assert r == pytest.approx(resolution(big[:2000]) * np.sqrt(2000 / 5000), rel=0.2)


def test_intrinsic_resolution_robust_ignores_duplicates_and_a_far_outlier():
    p = uniform_cloud(400, seed=9)
    d = np.linalg.norm(p[:, None] - p[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    robust = hgjax.intrinsic_resolution(p, robust=True)
    assert robust == pytest.approx(float(np.median(d.min(axis=1))), rel=1e-12)
    dup = np.concatenate([p, p[:150], p[:150]])
    # copies are at their location's distance, never 0: the median stays (copies only weigh it)
    assert hgjax.intrinsic_resolution(dup, robust=True) == pytest.approx(robust, rel=0.05)
    assert hgjax.intrinsic_resolution(dup) < 0.7 * hgjax.intrinsic_resolution(p)  # the mean drops
    far = np.concatenate([dup, [[1e4, 1e4, 1e4]]])
    assert hgjax.intrinsic_resolution(far, robust=True) == pytest.approx(robust, rel=0.02)
    assert hgjax.intrinsic_resolution(np.concatenate([p, [[1e4, 1e4, 1e4]]])) > 10 * robust  # the mean jumps


def test_intrinsic_resolution_all_equal_is_zero():
    assert hgjax.intrinsic_resolution(np.ones((10, 3))) == 0.0
    assert hgjax.intrinsic_resolution(np.ones((10, 3)), robust=True) == 0.0


def test_spatial_index_maps_back_to_the_caller():
    p = with_duplicates(seed=4)
    first, inverse = first_copies(p)
    index = SpatialIndex(p, dedupe=True)
    assert index.n == len(first) and index.n_caller == len(p)
    np.testing.assert_array_equal(index.to_caller(index.points), p)  # every copy gets its location
    np.testing.assert_array_equal(np.sort(index.order), np.sort(first))
    ext = index.caller_idx(np.array([[0, index.n]] * index.n))
    np.testing.assert_array_equal(ext[:, 1], len(p))  # the sentinel maps to N
    np.testing.assert_array_equal(p[ext[:, 0]], np.broadcast_to(index.points[0], (len(p), 3)))


def test_spatial_order_breaks_shared_cells_by_coordinates():
    # Two far-apart points stretch the grid, so the 300 points near the origin share a
    # handful of Morton cells and the coordinate tie-break decides their order.
    p = np.concatenate([uniform_cloud(300) * 1e-9, [[1.0, 1.0, 1.0], [-1.0, 0.5, 0.0]]])
    order = hgjax.spatial_order(p)
    np.testing.assert_array_equal(np.sort(order), np.arange(len(p)))
    perm = np.random.default_rng(4).permutation(len(p))
    np.testing.assert_array_equal(p[perm][hgjax.spatial_order(p[perm])], p[order])
    tied = p[order][1:-1]  # the near-origin points, between the two far ones in Z order
    assert (np.diff(tied[:, 0]) >= 0).all()  # one cell here: sorted by x


def test_spatial_order_of_a_large_cloud_is_the_lexicographic_order():
    # Above MORTON_SPLIT the codes are computed in two halves, in two threads; rounding to a
    # coarse grid makes many points share a code, so the coordinate tie-break matters too.
    from hgjax.neighbours import spatial
    n = spatial.MORTON_SPLIT + 4321
    p = np.round(uniform_cloud(n, seed=5) * 40) / 40
    p[::7] = p[1::7][:len(p[::7])]  # exact duplicates: broken by index
    lo, hi = p.min(axis=0), p.max(axis=0)
    q = ((p - lo) * ((2**spatial._MORTON_BITS - 1) / (hi - lo).max())).astype(np.uint64)
    code = sum(spatial._spread_bits(q[:, a]) << np.uint64(2 - a) for a in range(3))
    np.testing.assert_array_equal(hgjax.spatial_order(p), np.lexsort((p[:, 2], p[:, 1], p[:, 0], code)))


def test_knn_batches_queried_ahead_are_the_whole_query(monkeypatch):
    from hgjax.neighbours import spatial
    monkeypatch.setattr(spatial, "QUERY_ROWS", 64)  # 1000 rows: 16 batches, each queried ahead
    index = SpatialIndex(np.round(uniform_cloud(1000, seed=6) * 10) / 10, dedupe=True)  # many distance ties
    rows = np.random.default_rng(7).permutation(index.n)[:900]
    parts = list(spatial.knn_batches(index, 9, rows))
    assert [part for part, _, _ in parts] == spatial.batches(rows.size)
    want_idx, want_reach = index.neighbours(9, rows)
    np.testing.assert_array_equal(np.concatenate([idx for _, idx, _ in parts]), want_idx)
    np.testing.assert_array_equal(np.concatenate([reach for _, _, reach in parts]), want_reach)


@pytest.mark.parametrize("jitter", [0.0, 0.01])  # a lattice (distance ties everywhere) and a noisy one
def test_one_nearest_query_serves_spacing_and_ball_exactly(jitter):
    from hgjax.neighbours import spatial
    g = grid((12, 12, 3))
    index = SpatialIndex(g + np.random.default_rng(0).normal(0, jitter, g.shape), dedupe=True)
    rows = np.arange(index.n)
    spacing, reach = spatial.local_spacing(index, rows)
    half = 2.2 * spacing
    rk, parts = np.full(index.n, np.nan), []
    for batch in np.array_split(rows, 3):  # batches share their neighbours' r_k
        nearest = index.nearest(batch, 20)
        s, r = spatial.local_spacing(index, batch, query=nearest, rk=rk)
        idx, _ = index.cube(half[batch], batch, max_count=40, norm=2, query=nearest)
        want, _ = index.cube(half[batch], batch, capacity=7, max_count=40, norm=2)
        np.testing.assert_array_equal(idx, want)
        parts.append((s, r))
    np.testing.assert_array_equal(np.concatenate([s for s, _ in parts]), spacing)
    np.testing.assert_array_equal(np.concatenate([r for _, r in parts]), reach)
    # every ball: its points by (distance, global id), the point itself first
    dist = np.sqrt(((index.points[:, None] - index.points[None]) ** 2).sum(-1))
    for i, row in enumerate(index.cube(half, norm=2, max_count=40)[0]):
        row = row[row < index.n]
        assert row[0] == i
        key = [(dist[i, j], index.gid[j]) for j in row[1:]]
        assert key == sorted(key)
