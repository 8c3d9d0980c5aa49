"""Samplers: FPS backends against each other, voxel grid against a dictionary of voxels."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

import hgjax
from hgjax import samplers

needs_fpsample = pytest.mark.skipif(importlib.util.find_spec("fpsample") is None, reason="fpsample not installed")
needs_numba = pytest.mark.skipif(importlib.util.find_spec("numba") is None, reason="numba not installed")


def cloud(n, seed=0):
    return np.random.default_rng(seed).normal(size=(n, 3))


def voxel_naive(p, size):
    """Ranked representatives by a dictionary of voxels: population desc, then index."""
    cells = {}
    for i, cell in enumerate(map(tuple, np.floor((p - p.min(axis=0)) / size).astype(int))):
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
    p = cloud(600, seed=1).astype(dtype)
    fast = hgjax.farthest_point_sample(p, 0.3, start=start, backend="fpsample")
    slow = hgjax.farthest_point_sample(p, 0.3, start=start, backend="jax")
    assert fast.dtype == np.int64 and fast[0] == start
    np.testing.assert_array_equal(fast, slow)


@needs_fpsample
def test_fps_backends_agree_with_duplicates():
    base = cloud(200, seed=2)
    p = np.concatenate([base, base[::4], base[:3]])  # duplicates, some of the start point
    for ratio in (0.5, 1.0):  # 1.0 runs past the distinct points into the duplicates
        fast = hgjax.farthest_point_sample(p, ratio, start=0, backend="fpsample")
        np.testing.assert_array_equal(fast, hgjax.farthest_point_sample(p, ratio, start=0, backend="jax"))
    assert len(set(fast.tolist())) == len(p) and np.all(fast[200:] >= 200)  # duplicates last


@needs_fpsample
def test_fps_layout_replays_the_tree_build():
    # 1e5 points: summation order moves the float32 node means across points, so only a
    # replay of the build's own swaps finds where each row lands.
    import fpsample

    d = np.unique(cloud(100_000, seed=8).astype(np.float32), axis=0)
    layout = samplers._kd_layout(d)
    rows = np.linspace(0, len(d) - 1, 40).astype(np.int64)
    landed = [fpsample.bucket_fps_kdtree_sampling(d, 1, start_idx=int(r))[0] for r in rows]
    np.testing.assert_array_equal(landed, layout[rows])


@needs_fpsample
def test_fps_fast_path_honours_the_start_on_large_clouds(monkeypatch):
    import fpsample

    p = cloud(50_000, seed=8)
    monkeypatch.setattr(fpsample, "fps_sampling", None)  # the O(N M) fallback must not run
    for start in (0, 3750, 48750):
        fast = hgjax.farthest_point_sample(p, 0.002, start=start, backend="fpsample")
        np.testing.assert_array_equal(fast, hgjax.farthest_point_sample(p, 0.002, start=start, backend="jax"))


@needs_fpsample
def test_fps_fallback_when_the_start_is_not_honoured(monkeypatch):
    p = cloud(300, seed=3)
    want = hgjax.farthest_point_sample(p, 0.2, start=11, backend="jax")
    monkeypatch.setattr(samplers, "_kd_layout", lambda q: np.arange(q.shape[0])[::-1])
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
    with pytest.raises(ImportError, match="hgjax\\[fps\\]"):
        samplers.fps_backend("fpsample")
    p = np.array([[0.0, 0, 0], [1, 0, 0], [4, 0, 0], [2, 0, 0]])
    assert hgjax.farthest_point_sample(p, 0.75).tolist() == [0, 2, 3]


# ---------------------------------------------------------------- voxel grid
def test_voxel_size_matches_naive(dtype):
    p = cloud(2000, seed=4).astype(dtype)
    got = hgjax.voxel_sample(p, voxel_size=0.7)
    np.testing.assert_array_equal(got, voxel_naive(p.astype(np.float64), 0.7))
    assert got.dtype == np.int64


@needs_numba
@pytest.mark.parametrize("name", ["normal", "grid", "one_voxel"])
def test_voxel_table_matches_the_sort(name, dtype, monkeypatch):
    base = cloud(3000, seed=6)
    p = {"normal": base, "grid": np.stack(np.meshgrid(*[np.arange(12.0)] * 3), -1).reshape(-1, 3) * 0.25,
         "one_voxel": 1e-3 * base}[name].astype(dtype)  # grid: points on voxel faces
    calls = [lambda: hgjax.voxel_sample(p, voxel_size=0.7), lambda: hgjax.voxel_sample(p, 0.1),
             lambda: hgjax.voxel_sample(p, 0.1, voxel_size=2.0)]
    assert samplers._voxel_kernel() is not None
    table = [call() for call in calls]
    monkeypatch.setattr(samplers, "_voxel_kernel", lambda: None)
    for got, want in zip(table, [call() for call in calls]):
        np.testing.assert_array_equal(got, want)


@needs_numba
def test_voxel_table_ties_between_duplicated_locations(monkeypatch):
    # Two locations duplicated alike are equally near their voxel's centroid: the two paths
    # sum the centroid in another order, so rounding may pick either. Same voxels, each
    # represented by a point at the nearest distance.
    base = cloud(3000, seed=6)
    p = np.concatenate([base, base[::3], base[:5]])
    got = hgjax.voxel_sample(p, voxel_size=0.7)
    monkeypatch.setattr(samplers, "_voxel_kernel", lambda: None)
    want = hgjax.voxel_sample(p, voxel_size=0.7)
    _, voxel = np.unique(np.floor((p - p.min(axis=0)) / 0.7), axis=0, return_inverse=True)
    voxel = voxel.ravel()
    counts = np.bincount(voxel)
    centre = np.stack([np.bincount(voxel, p[:, k]) for k in range(3)], axis=1) / counts[:, None]
    dist = ((p - centre[voxel]) ** 2).sum(axis=1)
    got, want = got[np.argsort(voxel[got])], want[np.argsort(voxel[want])]
    np.testing.assert_array_equal(voxel[got], voxel[want])
    np.testing.assert_allclose(dist[got], dist[want], rtol=1e-12)
    assert np.all(dist[got] <= np.minimum.reduceat(dist[np.argsort(voxel)], np.cumsum(counts) - counts) * (1 + 1e-12))


def test_voxel_size_with_ratio_truncates_or_fills():
    p = cloud(500, seed=5)
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
    size = samplers._voxel_size_for(cols, origin, extent, m)
    assert m <= samplers._count_voxels(cols, origin, extent, size) <= 1.1 * m
    idx = hgjax.voxel_sample(p, ratio)
    np.testing.assert_array_equal(idx, hgjax.voxel_sample(p, voxel_size=size)[:m])


def test_voxel_float32_and_float64_and_inputs_untouched(dtype):
    p = cloud(1000, seed=6).astype(dtype)
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
    p = cloud(50)
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
