"""The tiled path: the same indices as one process whatever the tiles, verified halos, exact selection."""

import dataclasses
import shutil
import tempfile
import weakref

import jax
import numpy as np
import pytest

import hgjax
from fixtures import backend_compiles, box_union, grid
from hgjax import _stream, tiles
from hgjax.engine import _grid, _passes, _runners, select
from hgjax.neighbours import balls, spatial

KEYED = {"uniform": {"key": jax.random.key(3)}, "gfr": {"key": jax.random.key(4)}}
VARIANTS = [("ea", {}), ("mss", {}), ("lhf", {}), ("hkc", {}), ("hkf", {}), ("uniform", {}), ("gfr", {}), ("gfr", {"mode": "top"}), ("voxel", {}),
            ("hkc", {"variant": "reference"}), ("lhf", {"variant": "reference", "lengths": (4, 8)})]


@pytest.fixture(scope="module")
def smooth():
    return box_union(3000, seed=1)


@pytest.fixture(scope="module")
def rounded(smooth):
    """The box union rounded to 1 cm of its 6-unit extent: many equal distances and duplicates."""
    return np.round(smooth * 50) / 50


def _tiled(points, method, tile, **params):
    return tiles.resample(points, 0.2, method=method, tile=tile, **KEYED.get(method, {}), **params)


@pytest.mark.full
@pytest.mark.parametrize("method,params", VARIANTS, ids=[f"{m}-{p.get('variant', p.get('mode', 'default'))}" for m, p in VARIANTS])
@pytest.mark.parametrize("which", ["smooth", "rounded"])
def test_tiled_equals_one_process(method, params, which, request):
    p = request.getfixturevalue(which)
    want = hgjax.resample(p, 0.2, method=method, **KEYED.get(method, {}), **params)
    for tile in (1.4, 2.5):
        _, cloud = tiles.plan(p, 0.2, method="ea", tile=tile)
        assert len(cloud.members) >= 4
        np.testing.assert_array_equal(_tiled(p, method, tile, **params), want)


@pytest.mark.full
@pytest.mark.parametrize("method", ["ea", "lhf"])
def test_many_small_tiles_give_the_one_process_indices_and_compile_a_few_programs(smooth, method):
    want = hgjax.resample(smooth, 0.2, method=method)
    assert len(tiles.plan(smooth, 0.2, method=method, tile=0.6)[1].members) >= 300  # of about 8 points each
    with backend_compiles() as events:
        np.testing.assert_array_equal(_tiled(smooth, method, 0.6), want)
    assert len(events) <= _stream.CHUNK_BLOCKS.bit_length(), events  # a few chunk sizes, not one per tile
    with backend_compiles() as events:
        np.testing.assert_array_equal(_tiled(smooth, method, 0.8), want)
    assert events == []


def test_the_grid_is_planned_by_a_stable_sort_of_keys_of_any_width():
    rng = np.random.default_rng(5)
    for top, dtype in ((3, np.uint32), (70_000, np.uint32), (1 << 32, np.uint32), (1 << 40, np.uint64)):
        key = rng.integers(0, top, 50_000, dtype=np.uint64).astype(dtype)  # ties at every width
        np.testing.assert_array_equal(_grid.stable_order(key, top), np.argsort(key, kind="stable"), err_msg=str(top))


def test_points_on_tile_edges_are_owned_once():
    p = grid((9, 9, 9), 0.25)  # every coordinate on a tile edge
    _, cloud = tiles.plan(p, 0.2, method="ea", tile=0.5)
    owned = np.sort(np.concatenate(list(cloud.members.values())))
    np.testing.assert_array_equal(owned, np.arange(len(p)))
    for cell, gids in cloud.members.items():
        x = cloud.frame(gids)
        box_lo, box_hi = cloud.box(cell, 0.0)
        inner = (x < box_hi) | (x >= cloud.hi)  # half-open, the cloud's last plane with the last tile
        assert ((x >= box_lo) & inner).all()
    np.testing.assert_array_equal(tiles.resample(p, 0.3, method="lhf", tile=0.5, lengths=(4, 8)),
                                  hgjax.resample(p, 0.3, method="lhf", lengths=(4, 8)))


def test_halo_slabs_hold_every_point_of_the_box_and_no_other():
    lattice = grid((33, 33, 33), 1 / 16)  # coordinates on tile, sub-cell and halo-box edges
    rough = np.random.default_rng(0).uniform(0, 2, (3000, 3))
    for p in (lattice, rough):
        _, cloud = tiles.plan(p, 0.2, method="ea", tile=0.5)
        x_all = cloud.frame(np.arange(len(p)))
        for halo in (0.0, 1 / 16, 0.3, 0.7):
            for cell, core in cloud.members.items():
                gids, x, is_core = cloud.gather(cell, halo)
                box_lo, box_hi = cloud.box(cell, halo)
                inside = np.flatnonzero(((x_all >= box_lo) & (x_all < box_hi)).all(axis=1))
                np.testing.assert_array_equal(gids, np.union1d(inside, core))
                np.testing.assert_array_equal(gids[is_core], np.sort(core))
                np.testing.assert_array_equal(x, x_all[gids])


@pytest.mark.parametrize("method,params", [("hkc", {}), ("gfr", {"mode": "top"})])
def test_each_tile_is_gathered_once_per_halo(smooth, method, params, monkeypatch):
    seen = []
    gather = _grid.Cloud.gather
    monkeypatch.setattr(_grid.Cloud, "gather",
                        lambda self, cell, halo: seen.append((cell, halo)) or gather(self, cell, halo))
    tiles.resample(smooth, 0.2, method=method, tile=1.4, **params)
    assert len(seen) == len(set(seen)), sorted(seen)


class _Graph(dict):
    """A GFR tile graph the test can watch (module level: the spilled graphs are pickled)."""


@pytest.mark.full
@pytest.mark.parametrize("mode, disk_free", [("top", None), ("random", None), ("top", 0)])
def test_gfr_beyond_keep_points_spills_each_graph_between_passes(smooth, mode, disk_free, monkeypatch, tmp_path):
    """Above KEEP_POINTS the first pass keeps each tile's pair sums only (no graph outlives its
    tile in memory) and writes its tile to a temporary directory that the second pass reads
    and that is gone at the end; with no room on the disk the second pass builds the graphs
    again. The same indices as one process either way."""
    want = hgjax.resample(smooth, 0.2, method="gfr", mode=mode, key=jax.random.key(3))
    entry = hgjax.METHODS["gfr"]
    passes = entry.tiling.passes
    alive, alive_at_build = [0], []

    def freed():
        alive[0] -= 1

    def counted(*args):
        g = _Graph(passes.first(*args))
        alive[0] += 1
        weakref.finalize(g, freed)
        alive_at_build.append(alive[0])
        return g

    watched = dataclasses.replace(entry, tiling=dataclasses.replace(
        entry.tiling, passes=dataclasses.replace(passes, first=counted)))
    monkeypatch.setitem(hgjax.METHODS, "gfr", watched)
    monkeypatch.setattr(_runners, "KEEP_POINTS", 0)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    if disk_free is not None:
        monkeypatch.setattr(_passes.shutil, "disk_usage", lambda path: shutil._ntuple_diskusage(1, 1, disk_free))
    got = tiles.resample(smooth, 0.2, method="gfr", tile=1.4, mode=mode, key=jax.random.key(3))
    np.testing.assert_array_equal(got, want)
    cells = tiles.plan(smooth, 0.2, method="gfr", tile=1.4)[1].members
    assert len(cells) >= 4 and max(alive_at_build) == 1  # no graph outlives its tile
    # each graph built once and read back from the disk, or, with no room there, built again
    assert len(alive_at_build) == len(cells) * (1 if disk_free is None else 2)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.full
@pytest.mark.parametrize("method", ["ea", "hkc"])
def test_a_halo_given_too_small_grows_to_the_exact_result(smooth, method):
    plan, cloud = tiles.plan(smooth, 0.2, method=method, tile=1.5)
    small = dataclasses.replace(plan, halo=plan.halo / 50)
    for cell in cloud.members:
        g0, s0 = tiles.tile_scores(cloud, cell, plan)
        g1, s1 = tiles.tile_scores(cloud, cell, small)
        np.testing.assert_array_equal(g0, g1)
        np.testing.assert_array_equal(s0, s1)


def test_tile_order_does_not_matter(smooth):
    plan, cloud = tiles.plan(smooth, 0.2, method="ea", tile=1.5)
    cells = list(cloud.members)
    parts = {c: tiles.tile_scores(cloud, c, plan) for c in cells}
    keyed = lambda order: [(select.order_keys(parts[c][1], largest=True), parts[c][0]) for c in order]  # noqa: E731
    shuffled = [cells[i] for i in np.random.default_rng(0).permutation(len(cells))]
    np.testing.assert_array_equal(select.top_pairs(keyed(cells), plan.m), select.top_pairs(keyed(shuffled), plan.m))
    np.testing.assert_array_equal(select.top_pairs(keyed(cells), plan.m), hgjax.resample(smooth, 0.2, method="ea"))


@pytest.mark.parametrize("method", ["pca_ac", "fps"])
def test_global_methods_are_refused_with_tiles(smooth, method):
    with pytest.raises(ValueError, match=f"method '{method}' cannot run in tiles.*tile=None"):
        tiles.resample(smooth, 0.2, method=method, tile=1.0)
    assert len(tiles.resample(smooth, 0.2, method=method, tile=None)) == 600


def test_pca_ac_plans_one_tile_only(smooth):
    with pytest.raises(ValueError, match="method 'pca_ac' cannot run in tiles.*tile=None"):
        tiles.plan(smooth, 0.2, method="pca_ac", tile=1.0)
    assert tiles.plan(smooth, 0.2, method="pca_ac")[0].build == tiles.plan(smooth, 0.2, method="ea")[0].build


def test_gfr_reference_is_refused_with_tiles(smooth):
    with pytest.raises(ValueError, match="variant='reference' cannot run in tiles"):
        tiles.resample(smooth, 0.2, method="gfr", variant="reference", mode="top", tile=1.0)
    with pytest.raises(ValueError, match="variant='reference' cannot run in tiles"):
        tiles.plan(smooth, 0.2, method="gfr", variant="reference", tile=1.0)


@pytest.mark.parametrize("offset", [1000, 2**59], ids=["ids", "ids-beyond-one-key"])  # one int64 key, or lexsort
def test_knn_ties_are_broken_by_global_id(offset):
    p = grid((6, 6, 6))  # a lattice: ties everywhere
    gid = np.random.default_rng(0).permutation(len(p)) + offset
    index = spatial.SpatialIndex(p, gid=gid)
    idx, reach = index.neighbours(9, np.arange(index.n))
    dist = np.sqrt(((index.points[:, None] - index.points[None]) ** 2).sum(-1))
    g_sorted = index.gid[:-1]
    for i in range(index.n):
        key = np.where(np.arange(index.n) == i, -1.0, dist[i])
        want = np.lexsort((g_sorted, key))[:9]
        np.testing.assert_array_equal(idx[i], want)
        assert reach[i] == dist[i, want[-1]]


@pytest.mark.full
def test_mismatched_neighbourhoods_are_refused(smooth):
    nb = hgjax.neighbourhoods(smooth[:500], "hkc", kernel_size=5)
    with pytest.raises(ValueError, match="kernel_size=3 disagrees with the neighbourhoods, built with kernel_size=5"):
        hgjax.score(nb, "hkc", kernel_size=3)
    assert hgjax.score(nb, "hkc").shape == (500,)  # the recorded kernel_size is used
    lhf = hgjax.neighbourhoods(smooth[:500], "lhf", lengths=(3, 20))
    with pytest.raises(ValueError, match=r"lengths=\(8, 16\) disagrees"):
        hgjax.score(lhf, "lhf", lengths=(8, 16))
    with pytest.raises(ValueError, match="built for method 'lhf'; method 'ea' needs its own"):
        hgjax.score(lhf, "ea")
    hgjax.score(nb, "hkf")  # HKC and HKF share their neighbourhoods
    with pytest.raises(TypeError, match="nb must be hgjax.Neighbourhoods"):
        hgjax.score(None, "ea")


@pytest.mark.full
@pytest.mark.parametrize("method", ["hkc", "lhf", "ea"])
def test_one_far_outlier_changes_nothing(smooth, method):
    p = smooth.astype(np.float32)
    far = np.concatenate([p, np.array([[1e6, 1e6, 1e6]], np.float32)])
    a = hgjax.resample(p, 0.2, method=method)
    b = hgjax.resample(far, 0.2, method=method)
    b = b[b < len(p)]
    overlap = len(np.intersect1d(a, b)) / len(a)
    assert overlap >= 0.99, overlap


def _streamed_peak(path, tile) -> int:
    """Peak bytes NumPy and Python allocate (tracemalloc) during one EA run of the ``.npy`` at ``path``, memory-mapped."""
    import tracemalloc

    points = np.load(path, mmap_mode="r")
    tracemalloc.start()
    try:
        tiles.resample(points, 0.2, method="ea", tile=tile)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


@pytest.mark.full
def test_a_streamed_run_holds_a_tile_and_a_few_bytes_per_point(monkeypatch, tmp_path):
    """Memory of a streamed run is bounded by the tile: a memory-mapped cloud in tiles of about
    3,700 points holds about a quarter of what one tile of the whole cloud holds, and at four
    times the points (the same points per tile) it grows by at most 64 bytes per added point: the
    selection's per-point state (order keys, global ids, scores) and the tiled cloud's member ids,
    where one process grows by about 150. Above KEEP_POINTS no tile's index outlives it; the
    planning pass reads PASS_ROWS points at a time (both lowered to this size, as at 1e8). NumPy's
    and Python's allocations are counted (XLA's buffers and the k-d tree's nodes are not)."""
    monkeypatch.setattr(_runners, "KEEP_POINTS", 0)
    monkeypatch.setattr(_grid, "PASS_ROWS", 1 << 16)
    small, large = tmp_path / "small.npy", tmp_path / "large.npy"
    np.save(small, hgjax.eval.box_surface(200_000, seed=0).astype(np.float32))
    np.save(large, hgjax.eval.box_surface(800_000, seed=0).astype(np.float32))
    _streamed_peak(small, None)  # compiles the kernel, outside the counts
    whole, tiled = _streamed_peak(small, None), _streamed_peak(small, 0.25)
    bigger = _streamed_peak(large, 0.125)
    assert tiled < 0.4 * whole
    assert bigger - tiled < 64 * (800_000 - 200_000)


TINY = [("ea", {}), ("lhf", {}), ("mss", {}), ("hkc", {}), ("gfr", {"mode": "top"}), ("voxel", {})]


@pytest.mark.full
@pytest.mark.parametrize("method,params", TINY, ids=[m for m, _ in TINY])
def test_tiles_smaller_than_the_spacing_equal_one_process(method, params):
    """A tile holding fewer points than a neighbourhood grows its halo until it holds the whole
    neighbourhood (its k-th point is beyond the tile: no radius is known to hold it)."""
    p = hgjax.eval.box_union_cloud(seed=5, n_points=200).points
    np.testing.assert_array_equal(tiles.resample(p, 0.2, method=method, tile=0.05, **params),
                                  hgjax.resample(p, 0.2, method=method, **params))


@pytest.fixture(scope="module")
def sparse_cube():
    """100 random points in the unit cube: a spacing of about 0.27, so tiles of 0.005 hold one point or none."""
    return np.random.default_rng(5).random((100, 3))


@pytest.mark.full
@pytest.mark.parametrize("tile", [0.005, 0.02, 0.1, 1.0])
@pytest.mark.parametrize("method", ["hkc", "hkf"])
def test_cube_tiles_of_any_size_give_the_one_process_indices_and_scores(sparse_cube, method, tile):
    want_idx, want_scores = hgjax.resample(sparse_cube, 0.2, method=method, return_scores=True)
    idx, scores = tiles.resample(sparse_cube, 0.2, method=method, tile=tile, return_scores=True)
    np.testing.assert_array_equal(idx, want_idx)
    assert np.asarray(scores).tobytes() == np.asarray(want_scores).tobytes()


@pytest.mark.parametrize("n", [2, 10, balls.LOCAL_K, balls.LOCAL_K + 1, 40])
def test_cube_reach_is_unbounded_where_the_index_holds_too_few_locations_for_the_spacing(n):
    """A tile's spacing estimate reads LOCAL_K neighbours; with fewer locations in its index it read fewer
    than the whole cloud would, so no halo short of the whole cloud holds what it needs."""
    index = spatial.SpatialIndex(np.random.default_rng(n).random((n, 3)), dedupe=True)
    build = balls.resolve(balls.build_params(d_factor=1.6), None)
    reach = np.concatenate([r for _, _, _, r in balls.row_batches(index, np.arange(n), build)])
    assert reach.shape == (n,)
    assert np.isinf(reach).all() if n <= balls.LOCAL_K else np.isfinite(reach).all()


@pytest.mark.full
@pytest.mark.parametrize("method", ["ea", "lhf"])
def test_float32_far_from_the_origin_tiles_as_one_process(method):
    """At +1e7 float32 rounds the cloud to a unit grid: many duplicates and ties, the same kept set."""
    p = (hgjax.eval.box_union_cloud(seed=5, n_points=600).points + 1e7).astype(np.float32)
    np.testing.assert_array_equal(tiles.resample(p, 0.2, method=method, tile=0.5),
                                  hgjax.resample(p, 0.2, method=method))


@pytest.mark.parametrize("tile,scale", [(1e-9, 1.0), (0.5, 1e12)])
def test_too_many_tiles_is_an_error_naming_tile(tile, scale):
    p = hgjax.eval.box_union_cloud(seed=0, n_points=300).points * scale
    with pytest.raises(ValueError, match=r"tile=.* cuts the cloud's extent .* into .* tiles .*; at most \d+: pass a larger tile"):
        tiles.resample(p, 0.2, method="ea", tile=tile)
