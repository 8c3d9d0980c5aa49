"""Samplers: FPS backends against each other, voxel grid against a dictionary of voxels."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

import hgjax
from fixtures import grid, normal_cloud
from hgjax import samplers

needs_fpsample = pytest.mark.skipif(importlib.util.find_spec("fpsample") is None, reason="fpsample not installed")
needs_numba = pytest.mark.skipif(importlib.util.find_spec("numba") is None, reason="numba not installed")


MUG = Path(__file__).resolve().parents[2] / "shared" / "data" / "scans" / "scan_table_mug.ply"


def voxel_naive(p, size):
    """Ranked representatives by a dictionary of voxels: population desc, then index. Centroids in the
    grid's frame (the points minus its origin, their minimum corner), as voxel_sample sums them."""
    p = p - p.min(axis=0)
    cells = {}
    for i, cell in enumerate(map(tuple, np.floor(p / size).astype(int))):
        cells.setdefault(cell, []).append(i)
    reps = []
    for members in cells.values():
        centroid = p[members].mean(axis=0)
        dist = ((p[members] - centroid) ** 2).sum(axis=1)
        reps.append((-len(members), members[int(np.argmin(dist))]))
    return np.array([i for _, i in sorted(reps)])


# ---------------------------------------------------------------- farthest point sampling
@needs_fpsample
@pytest.mark.parametrize("start", [0, 7])
def test_fps_backends_agree(dtype, start):
    p = normal_cloud(600, seed=1).astype(dtype)
    fast = hgjax.farthest_point_sample(p, 0.3, start=start, backend="fpsample")
    slow = hgjax.farthest_point_sample(p, 0.3, start=start, backend="jax")
    assert fast.dtype == np.int64 and fast[0] == start
    np.testing.assert_array_equal(fast, slow)


@needs_fpsample
def test_fps_backends_agree_with_duplicates():
    base = normal_cloud(200, seed=2)
    p = np.concatenate([base, base[::4], base[:3]])  # duplicates, some of the start point
    for ratio in (0.5, 1.0):  # 1.0 runs past the distinct points into the duplicates
        fast = hgjax.farthest_point_sample(p, ratio, start=0, backend="fpsample")
        np.testing.assert_array_equal(fast, hgjax.farthest_point_sample(p, ratio, start=0, backend="jax"))
    assert len(set(fast.tolist())) == len(p) and np.all(fast[200:] >= 200)  # duplicates last


@needs_fpsample
def test_fps_row_replays_the_tree_build():
    # 1e5 points: summation order moves the float32 node means across points, so only a
    # replay of the build's own swaps finds where each row lands.
    import fpsample

    d = np.unique(normal_cloud(100_000, seed=8).astype(np.float32), axis=0)
    targets = np.linspace(0, len(d) - 1, 40).astype(np.int64)
    landed = [fpsample.bucket_fps_kdtree_sampling(d, 1, start_idx=samplers._kd_row(d, int(t)))[0] for t in targets]
    np.testing.assert_array_equal(landed, targets)


def test_fps_distinct_rows_match_np_unique():
    rng = np.random.default_rng(4)
    q = rng.integers(-3, 4, (3000, 3)).astype(np.float32) * np.float32(0.5)  # many duplicates, equal x and y
    q[:5] = [[0.0, -0.0, 1.0], [-0.0, 0.0, 1.0], [0.0, 0.0, -0.0], [-0.0, -0.0, 0.0], [1e-30, 0, 0]]
    first, group = samplers._distinct_rows(q)
    _, want_first, want_group = np.unique(q, axis=0, return_index=True, return_inverse=True)
    np.testing.assert_array_equal(first, want_first)
    np.testing.assert_array_equal(group, want_group.ravel())


@needs_fpsample
def test_fps_fast_path_honours_the_start_on_large_clouds(monkeypatch):
    import fpsample

    p = normal_cloud(50_000, seed=8)
    monkeypatch.setattr(fpsample, "fps_sampling", None)  # the O(N M) fallback must not run
    for start in (0, 3750, 48750):
        fast = hgjax.farthest_point_sample(p, 0.002, start=start, backend="fpsample")
        np.testing.assert_array_equal(fast, hgjax.farthest_point_sample(p, 0.002, start=start, backend="jax"))


@needs_fpsample
def test_fps_fallback_when_the_start_is_not_honoured(monkeypatch):
    p = normal_cloud(300, seed=3)
    want = hgjax.farthest_point_sample(p, 0.2, start=11, backend="jax")
    monkeypatch.setattr(samplers, "_kd_row", lambda q, target: q.shape[0] - 1 - target)
    np.testing.assert_array_equal(hgjax.farthest_point_sample(p, 0.2, start=11, backend="fpsample"), want)


def test_fps_backend_choice(monkeypatch):
    installed = importlib.util.find_spec("fpsample") is not None
    assert samplers.fps_backend("auto") == ("fpsample" if installed else "jax")  # the suite runs on CPU
    assert samplers.fps_backend("jax") == "jax"
    with pytest.raises(ValueError, match="backend"):
        samplers.fps_backend("gpu")
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name: None if name == "fpsample" else real(name))
    assert samplers.fps_backend("auto") == "jax"
    with pytest.raises(ImportError, match=r'pip install "\.\[fps\]"'):
        samplers.fps_backend("fpsample")
    p = np.array([[0.0, 0, 0], [1, 0, 0], [4, 0, 0], [2, 0, 0]])
    assert hgjax.farthest_point_sample(p, 0.75).tolist() == [0, 2, 3]


# ---------------------------------------------------------------- voxel grid
def test_voxel_size_matches_naive(dtype):
    p = normal_cloud(2000, seed=4).astype(dtype)
    got = hgjax.voxel_sample(p, voxel_size=0.7)
    np.testing.assert_array_equal(got, voxel_naive(p.astype(np.float64), 0.7))
    assert got.dtype == np.int64


@needs_numba
@pytest.mark.parametrize("name", ["normal", "grid", "one_voxel"])
def test_voxel_table_matches_the_sort(name, dtype, monkeypatch):
    base = normal_cloud(3000, seed=6)
    p = {"normal": base, "grid": grid((12, 12, 12), 0.25),
         "one_voxel": 1e-3 * base}[name].astype(dtype)  # grid: points on voxel faces
    calls = [lambda: hgjax.voxel_sample(p, voxel_size=0.7), lambda: hgjax.voxel_sample(p, 0.1),
             lambda: hgjax.voxel_sample(p, 0.1, voxel_size=2.0)]
    assert samplers._voxel_kernels() is not None
    table = [call() for call in calls]
    monkeypatch.setattr(samplers, "_voxel_kernels", lambda: None)
    for got, want in zip(table, [call() for call in calls]):
        np.testing.assert_array_equal(got, want)


@needs_numba
@pytest.mark.parametrize("seed", range(4))
def test_voxel_table_ties_between_duplicated_locations(seed, dtype, monkeypatch):
    # Locations duplicated alike are equally near their voxel's centroid: both paths sum
    # each centroid in index order, so they round alike and give the tie to the lowest index.
    rng = np.random.default_rng(seed)
    base = normal_cloud(3000, seed=6) * rng.uniform(0.01, 100)
    p = np.concatenate([base, base[::3], base[:5]])[rng.permutation(4005)].astype(dtype)
    calls = [lambda: hgjax.voxel_sample(p, voxel_size=float(np.ptp(p)) / 9), lambda: hgjax.voxel_sample(p, 0.1)]
    table = [call() for call in calls]
    monkeypatch.setattr(samplers, "_voxel_kernels", lambda: None)
    for got, want in zip(table, [call() for call in calls]):
        np.testing.assert_array_equal(got, want)


def test_voxel_size_with_ratio_truncates_or_fills():
    p = normal_cloud(500, seed=5)
    ranked = hgjax.voxel_sample(p, voxel_size=1.5)
    np.testing.assert_array_equal(hgjax.voxel_sample(p, 10 / 500, voxel_size=1.5), ranked[:10])
    filled = hgjax.voxel_sample(p, 0.5, voxel_size=1.5)  # more than the occupied voxels
    assert len(filled) == 250 and len(set(filled.tolist())) == 250
    np.testing.assert_array_equal(filled[: len(ranked)], ranked)
    rest = filled[len(ranked):]
    assert np.all(np.diff(rest) > 0) and not set(rest.tolist()) & set(ranked.tolist())


@pytest.mark.parametrize("ratio", [0.02, 0.1, 0.3])
def test_voxel_search_reaches_the_count(ratio):
    p = hgjax.eval.box_surface(20_000, seed=0)
    cols = np.array(p.T, order="C")
    origin = cols.min(axis=1)
    m = int(np.ceil(ratio * len(p)))
    extent = float(np.ptp(p, axis=0).max())
    size, voxel, v = samplers._voxel_search(cols, origin, extent, m)
    assert m <= v <= 1.1 * m and v == samplers._count_voxels(cols, origin, extent, size)[0]
    assert voxel.shape == (len(p),) and np.array_equal(np.unique(voxel), np.arange(v))
    idx = hgjax.voxel_sample(p, ratio)
    np.testing.assert_array_equal(idx, hgjax.voxel_sample(p, voxel_size=size)[:m])


@needs_numba
def test_voxel_counts_match_the_sort_on_many_grids(monkeypatch):
    # The table counts a grid and the nested grid of twice the edge in one pass; sizes
    # sweep many grid dimensions (a multiplicative hash clusters on some of them).
    p = np.concatenate([normal_cloud(4000, seed=8), 0.01 * normal_cloud(2000, seed=9), normal_cloud(500, seed=10)[:, :1] * [1, 0, 0]])
    cols = np.asarray(p).T
    origin, top = samplers._axis_bounds(cols)
    extent = float((top - origin).max())
    sizes = extent / np.geomspace(3, 3000, 25)
    table = [samplers._count_voxels(cols, origin, extent, h, coarse=True) for h in sizes]
    monkeypatch.setattr(samplers, "_voxel_kernels", lambda: None)
    sort = [samplers._count_voxels(cols, origin, extent, h, coarse=True) for h in sizes]
    assert table == sort
    assert all(c2 == samplers._count_voxels(cols, origin, extent, 2 * h)[0] for h, (_, c2) in zip(sizes, sort))


@pytest.mark.skipif(not MUG.exists(), reason="shared data not present")
@pytest.mark.parametrize("duplicated", [False, True])
def test_voxel_search_lands_on_a_real_scan_in_one_assigning_pass(duplicated, monkeypatch):
    # Uneven density: a subsample misses sparse voxels; the full-cloud count of two nested
    # grids and the saturating model still bring the first assigned grid into range.
    scan = hgjax.io.read_points(MUG).points
    if duplicated:
        rng = np.random.default_rng(0)
        scan = np.concatenate([scan, scan[rng.choice(len(scan), len(scan) // 3, replace=False)]])
        scan = scan[rng.permutation(len(scan))]
    passes = []
    grid = samplers._voxel_grid
    monkeypatch.setattr(samplers, "_voxel_grid", lambda *a: passes.append(a[3]) or grid(*a))
    for ratio in (0.05, 0.2, 0.4):
        passes.clear()
        idx = hgjax.voxel_sample(scan, ratio)
        assert len(passes) == 1 and len(idx) == int(np.ceil(ratio * len(scan)))


def test_voxel_float32_and_float64_and_inputs_untouched(dtype):
    p = normal_cloud(1000, seed=6).astype(dtype)
    keep = p.copy()
    p.flags.writeable = False
    idx = hgjax.voxel_sample(p, 0.1)
    assert len(idx) == 100 and len(set(idx.tolist())) == 100
    fps = hgjax.farthest_point_sample(p, 0.1)
    assert len(set(fps.tolist())) == 100
    np.testing.assert_array_equal(p, keep)


# ---------------------------------------------------------------- validation
def test_invalid_arguments_fail_before_jax(monkeypatch):
    monkeypatch.setattr(samplers, "_fps", None)  # any JAX call would raise TypeError: not callable
    p = normal_cloud(50)
    cases = [
        (lambda: hgjax.voxel_sample(p), ValueError, "ratio or voxel_size"),
        (lambda: hgjax.voxel_sample(p, voxel_size=-1.0), ValueError, "voxel_size"),
        (lambda: hgjax.voxel_sample(p, voxel_size="1"), TypeError, "voxel_size"),
        (lambda: hgjax.voxel_sample(p, voxel_size=1e-9), ValueError, "voxel_size must be at least"),
        (lambda: hgjax.voxel_sample(p, 2.0, voxel_size=1.0), ValueError, "ratio"),
        (lambda: hgjax.farthest_point_sample(p, 0.2, backend="gpu"), ValueError, "backend"),
        (lambda: hgjax.farthest_point_sample(p, 0.2, start=50, backend="jax"), ValueError, "start"),
        (lambda: hgjax.farthest_point_sample(p, 0.2, start=1.0, backend="jax"), TypeError, "start"),
        (lambda: hgjax.farthest_point_sample(p[:, :2], 0.2, backend="jax"), ValueError, "points"),
    ]
    for call, error, match in cases:
        with pytest.raises(error, match=match):
            call()
