"""Baselines (EA, PCA-AC, GFR selection) and samplers (uniform, voxel, fps) against naive NumPy loops.

GFR's graph and score against naive references are in tests/test_gfr.py.
"""

from __future__ import annotations

import importlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.cluster.hierarchy import fcluster, linkage

import hgjax
import naive
from conftest import TOL
from fixtures import box_surface, degenerate_clouds, grid, uniform_cloud

eigen = importlib.import_module("hgjax.scores.eigen")
pca_ac_module = importlib.import_module("hgjax.scores.pca_ac")
assert pca_ac_module is hgjax.scores.pca_ac  # the module, not a function of the same name

NEW_METHODS = ("gfr", "ea", "pca_ac", "uniform", "voxel", "fps")
KEYED = ("gfr", "uniform")


def spacing(points, idx):
    """Distance from each selected point to the closest one selected before it."""
    return np.array([np.sqrt(((points[idx[:i]] - points[idx[i]]) ** 2).sum(1).min()) for i in range(1, len(idx))])


def tol(dtype):
    return TOL[np.dtype(dtype)]


def scores_of(points, method, **params):
    """The composition neighbourhoods -> score, as NumPy."""
    return np.asarray(hgjax.score(hgjax.neighbourhoods(points, method, **params), method, **params))


# ---------------------------------------------------------------- scores vs naive
@pytest.mark.parametrize("k", [16, 5])
def test_ea_matches_naive(dtype, k):
    p = uniform_cloud(400, seed=2, scale=3.0)
    want = naive.ea(p, k)
    got = scores_of(p.astype(dtype), "ea", k=k)
    assert got.dtype == dtype
    np.testing.assert_allclose(got, want, rtol=tol(dtype), atol=tol(dtype) * want.max())


def hard_symmetric_3x3(seed=0):
    """(M, 3, 3) symmetric matrices that stress an eigensolver: random spectra over 12
    decades, exact and near-double or triple eigenvalues, planar and linear (rank 2, 1) and
    zero matrices, each in a random rotation."""
    rng = np.random.default_rng(seed)
    spectra = [rng.random(3) * 10.0 ** rng.uniform(-6, 6) for _ in range(200)]
    spectra += [[1, 1, 2], [1, 2, 2], [3, 3, 3], [1, 1 + 1e-9, 5], [0, 1, 1], [0, 0, 1], [0, 0, 0], [1e-12, 1, 1]]
    rot = np.linalg.qr(rng.normal(size=(len(spectra), 3, 3)))[0]
    return np.einsum("mij,mj,mkj->mik", rot, np.asarray(spectra, dtype=float), rot)


def test_smallest_eigenvalue_matches_lapack(dtype):
    m = hard_symmetric_3x3()
    ref = np.linalg.eigvalsh(m)
    got = np.asarray(jax.vmap(eigen.smallest_eigenvalue)(jnp.asarray(m.astype(dtype))))
    assert got.dtype == dtype
    scale = np.abs(ref).max(axis=1)  # the error bound of any backward-stable solver
    assert np.all(np.abs(got - ref[:, 0]) <= 16 * np.finfo(dtype).eps * scale + 1e-300)


@pytest.mark.full
def test_smallest_eigenvalue_gradient(dtype):
    m = hard_symmetric_3x3(seed=1).astype(dtype)
    ref = np.linalg.eigh(m.astype(np.float64))
    grad = np.asarray(jax.vmap(jax.grad(eigen.smallest_eigenvalue))(jnp.asarray(m)))
    assert np.all(np.isfinite(grad))
    gap = ref.eigenvalues[:, 1] - ref.eigenvalues[:, 0]
    simple = gap > 1e-3 * np.abs(ref.eigenvalues).max(axis=1)
    v0 = ref.eigenvectors[:, :, 0]
    np.testing.assert_allclose(grad[simple], np.einsum("mi,mj->mij", v0, v0)[simple], atol=100 * TOL[dtype])


def _entries(m):
    """The six entries (``_common.PAIRS`` order) of (M, 3, 3) matrices, each as an (M,) array."""
    return tuple(jnp.asarray(m[:, i, j]) for i, j in ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)))


def test_eigenvalues_of_six_entries_match_lapack(dtype):
    m = hard_symmetric_3x3(seed=2)
    ref = np.linalg.eigvalsh(m)
    got = np.stack([np.asarray(x) for x in jax.jit(jax.vmap(eigen.eigenvalues))(_entries(m.astype(dtype)))], 1)
    assert got.dtype == dtype and np.all(np.diff(got, axis=1) >= 0)
    scale = np.abs(ref).max(axis=1, keepdims=True)
    assert np.all(np.abs(got - ref) <= 16 * np.finfo(dtype).eps * scale + 1e-300)


def test_eigenvalues_of_six_entries_derivative_is_v_dc_v(dtype):
    m = hard_symmetric_3x3(seed=3).astype(dtype)
    ref = np.linalg.eigh(m.astype(np.float64))
    dm = np.random.default_rng(4).normal(size=m.shape)
    dm = (dm + dm.transpose(0, 2, 1)).astype(dtype)  # a symmetric direction
    _, tangent = jax.jit(jax.vmap(lambda e, d: jax.jvp(eigen.eigenvalues, (e,), (d,))))(_entries(m), _entries(dm))
    tangent = np.stack([np.asarray(t) for t in tangent], 1)
    assert np.all(np.isfinite(tangent))
    want = np.einsum("mik,mij,mjk->mk", ref.eigenvectors, dm.astype(np.float64), ref.eigenvectors)
    lam = ref.eigenvalues
    gaps = np.diff(lam, axis=1)
    own_gap = np.stack([gaps[:, 0], np.minimum(gaps[:, 0], gaps[:, 1]), gaps[:, 1]], 1)  # to the nearest eigenvalue
    simple = own_gap > 1e-3 * np.abs(lam).max(axis=1, keepdims=True)
    np.testing.assert_allclose(tangent[simple], want[simple], atol=100 * TOL[dtype] * np.abs(dm).max())


def test_ea_with_duplicates_matches_naive_on_the_distinct_points():
    base = uniform_cloud(60, seed=5)
    p = np.concatenate([base, base[:30], base[:5]])  # 60 distinct points, 35 copies
    want = naive.ea(base, 16)
    got = scores_of(p, "ea")  # dedupe=True by default: a copy scores as its first copy
    np.testing.assert_allclose(got, np.concatenate([want, want[:30], want[:5]]), rtol=1e-10, atol=1e-14)
    paper = scores_of(p, "ea", dedupe=False)
    np.testing.assert_allclose(paper, naive.ea(p, 16), rtol=1e-10, atol=1e-14)


def test_scores_follow_a_permutation():
    p = uniform_cloud(300, seed=3)
    perm = np.random.default_rng(0).permutation(len(p))
    np.testing.assert_array_equal(scores_of(p[perm], "ea"), scores_of(p, "ea")[perm])
    for method in ("ea", "pca_ac"):
        a = hgjax.resample(p, 0.2, method=method)
        assert set(perm[hgjax.resample(p[perm], 0.2, method=method)].tolist()) == set(a.tolist())


def test_chunk_size(dtype):
    p = uniform_cloud(700, seed=15).astype(dtype)
    nb = hgjax.neighbourhoods(p, "ea")
    np.testing.assert_array_equal(hgjax.score(nb, "ea", chunk_size=128), hgjax.score(nb, "ea"))


def test_scores_do_not_modify_input():
    p = uniform_cloud(200, seed=4)
    copy = p.copy()
    for method in ("gfr", "ea", "pca_ac"):
        hgjax.resample(p, 0.2, method=method, key=jax.random.key(0))
        hgjax.soft_resample(p, 0.2, method=method)
    np.testing.assert_array_equal(p, copy)


@pytest.mark.full
@pytest.mark.parametrize("name", sorted(degenerate_clouds()))
def test_degenerate_clouds_give_finite_scores(name):
    p = degenerate_clouds()[name]
    for method in ("gfr", "ea", "pca_ac"):
        for values in (scores_of(p, method), np.asarray(hgjax.soft_score(hgjax.neighbourhoods(p, method), method))):
            assert np.isfinite(values).all() and (values >= 0).all()
    labels = hgjax.scores.pca_ac.ward_1d(scores_of(p, "pca_ac"), 2)
    assert labels.shape == (len(p),) and set(labels.tolist()) <= {0, 1}
    if name == "all_equal":
        assert not scores_of(p, "gfr").any() and not scores_of(p, "ea").any()
    if name in ("coplanar", "planar_grid"):
        assert scores_of(p, "ea").max() < 1e-12


# ---------------------------------------------------------------- PCA-AC
@pytest.mark.parametrize("round_share", [64, 10**9], ids=["rounds", "heap"])
def test_ward_1d_matches_scipy(round_share, monkeypatch):
    monkeypatch.setattr(pca_ac_module, "_ROUND_MIN_SHARE", round_share)
    rng = np.random.default_rng(6)
    for trial in range(30):
        v = rng.random(int(rng.integers(2, 150))) ** int(rng.integers(1, 4))
        k = int(rng.integers(1, min(len(v), 12) + 1))
        ours = hgjax.scores.pca_ac.ward_1d(v, k)
        theirs = fcluster(linkage(v[:, None], method="ward"), k, criterion="maxclust")
        pairs = set(zip(ours.tolist(), theirs.tolist()))
        assert len(pairs) == len(set(ours.tolist())) == len(set(theirs.tolist())) == k, trial
        means = [v[ours == c].mean() for c in range(k)]
        assert np.all(np.diff(means) > 0)  # numbered by increasing variation


def test_ward_1d_equal_runs_match_scipy_and_per_value(monkeypatch):
    """Runs of equal values enter as one cluster (cost 0): the same labels as one cluster per value, and scipy's."""
    rng = np.random.default_rng(7)
    for trial in range(40):
        base = rng.random(int(rng.integers(2, 60))) ** 2
        v = np.concatenate([base, np.repeat(rng.choice(base, 3), rng.integers(60, 150, 3)), np.zeros(100)])
        rng.shuffle(v)
        k = int(rng.integers(2, 8))
        ours = hgjax.scores.pca_ac.ward_1d(v, k)
        monkeypatch.setattr(pca_ac_module, "_RUN_MIN", 10**9)
        np.testing.assert_array_equal(hgjax.scores.pca_ac.ward_1d(v, k), ours)
        monkeypatch.undo()
        theirs = fcluster(linkage(v[:, None], method="ward"), k, criterion="maxclust")
        assert len(set(zip(ours.tolist(), theirs.tolist()))) == k, trial


def test_pca_ac_keeps_what_ea_keeps():
    p = uniform_cloud(500, seed=7)
    a = hgjax.resample(p, 0.2, method="pca_ac", n_clusters=4)
    b = hgjax.resample(p, 0.2, method="ea")
    assert set(a.tolist()) == set(b.tolist())
    labels = hgjax.scores.pca_ac.ward_1d(scores_of(p, "pca_ac"), 4)
    assert np.all(np.diff(labels[a]) <= 0)  # highest cluster numbers first
    _, scores = hgjax.tiles.resample(p, 0.2, method="ea", return_scores=True)
    np.testing.assert_array_equal(hgjax.scores.pca_ac.keep(scores, 100, n_clusters=4), a)


@pytest.mark.parametrize("n_clusters", [2, 5])
def test_pca_ac_ranks_the_scores_ea_ranks(dtype, n_clusters):
    """PCA-AC's clusters are intervals of EA's variation, scored by the same one-tile engine: the
    same indices in the same order, and the same scores (float32 included)."""
    p = box_surface(20000, seed=3).astype(dtype)
    idx, scores = hgjax.tiles.resample(p, 0.2, method="pca_ac", n_clusters=n_clusters, return_scores=True)
    ea_idx, ea_scores = hgjax.tiles.resample(p, 0.2, method="ea", return_scores=True)
    assert scores.dtype == dtype
    np.testing.assert_array_equal(scores, ea_scores)
    np.testing.assert_array_equal(idx, ea_idx)
    np.testing.assert_array_equal(idx, hgjax.resample(p, 0.2, method="pca_ac", n_clusters=n_clusters))


def test_pca_ac_checks_n_clusters_before_scoring(monkeypatch):
    monkeypatch.setattr(hgjax.engine, "tile_scores", lambda *a, **k: pytest.fail("scored before the check"))
    with pytest.raises(ValueError, match="n_clusters"):
        hgjax.resample(uniform_cloud(100), 0.2, method="pca_ac", n_clusters=0)


# ---------------------------------------------------------------- samplers
def test_fps_matches_naive(dtype):
    p = uniform_cloud(500, seed=8)
    want = naive.fps(p, 100)
    got = hgjax.farthest_point_sample(p.astype(dtype), 0.2)
    if dtype == np.float64:
        np.testing.assert_array_equal(got, want)
    np.testing.assert_allclose(spacing(p, got), spacing(p, want), rtol=tol(dtype))


def test_fps_properties():
    p = np.concatenate([uniform_cloud(300, seed=9), uniform_cloud(20, seed=9)])  # 20 exact duplicates
    idx = hgjax.farthest_point_sample(p, 1.0, start=5)
    assert idx[0] == 5 and len(set(idx.tolist())) == len(p)
    gaps = spacing(p, idx)
    assert np.all(np.diff(gaps) <= 0)
    assert not gaps[-20:].any() and gaps[:-20].all()  # the duplicates come last


def test_voxel_one_point_per_voxel():
    centres = grid((4, 4, 4)) + 0.5
    p = np.concatenate([centres - 0.01, centres + 0.02, centres])  # tight clusters of three
    idx = hgjax.voxel_sample(p, 1 / 3)  # 64 voxels, one per cluster, its most central point
    np.testing.assert_array_equal(np.sort(idx), np.arange(128, 192))


def test_voxel_exact_count_with_duplicates():
    p = np.concatenate([np.zeros((50, 3)), uniform_cloud(10, seed=10)])
    idx = hgjax.voxel_sample(p, 0.5)  # 11 distinct positions < 30 requested
    assert len(idx) == 30 and len(set(idx.tolist())) == 30


@pytest.mark.parametrize("method", KEYED)
def test_same_key_same_output(method):
    p = uniform_cloud(400, seed=11)
    run = lambda seed: hgjax.resample(p, 0.2, method=method, key=jax.random.key(seed))
    np.testing.assert_array_equal(run(0), run(0))
    assert set(run(0).tolist()) != set(run(1).tolist())


def test_gfr_top_mode_keeps_largest_scores():
    p = uniform_cloud(300, seed=12)
    idx = hgjax.resample(p, 0.1, method="gfr", mode="top")
    s = scores_of(p, "gfr")
    assert s[idx].min() >= np.sort(s)[-len(idx)]
    np.testing.assert_array_equal(hgjax.keep(s, 0.1, method="gfr", mode="top"), idx)
    with pytest.raises(ValueError, match=r"key=jax\.random\.key\(0\)"):
        hgjax.keep(s, 0.1, method="gfr")  # the default mode samples
    keyed = hgjax.keep(s, 0.1, method="gfr", key=jax.random.key(3))
    np.testing.assert_array_equal(keyed, hgjax.resample(p, 0.1, method="gfr", key=jax.random.key(3)))


# ---------------------------------------------------------------- registry and errors
@pytest.mark.parametrize("method", NEW_METHODS)
@pytest.mark.parametrize("ratio", [0.05, 0.33, 1.0])
def test_resample_counts(method, ratio):
    p = uniform_cloud(257, seed=13).astype(np.float32)
    idx = hgjax.resample(p, ratio, method=method, key=jax.random.key(0))
    assert idx.dtype == np.int64 and idx.shape == (int(np.ceil(ratio * 257)),)
    assert len(set(idx.tolist())) == len(idx) and idx.min() >= 0 and idx.max() < 257


@pytest.mark.full
@pytest.mark.parametrize("method", NEW_METHODS)
@pytest.mark.parametrize("name", sorted(degenerate_clouds()))
def test_resample_degenerate(method, name):
    p = degenerate_clouds()[name]
    idx = hgjax.resample(p, 0.3, method=method, key=jax.random.key(0))
    assert len(set(idx.tolist())) == len(idx) == int(np.ceil(0.3 * len(p)))


@pytest.mark.parametrize("method", KEYED)
def test_missing_or_bad_key(method):
    p = uniform_cloud(50)
    with pytest.raises(ValueError, match=r"key=jax\.random\.key\(0\)"):
        hgjax.resample(p, 0.2, method=method)
    with pytest.raises(TypeError, match="key"):
        hgjax.resample(p, 0.2, method=method, key=0)


@pytest.mark.parametrize("method", NEW_METHODS)
def test_bad_ratio_and_points(method):
    p = uniform_cloud(50)
    for ratio, error in [(0.0, ValueError), (1.5, ValueError), (float("nan"), ValueError), ("a", TypeError)]:
        with pytest.raises(error, match="ratio"):
            hgjax.resample(p, ratio, method=method, key=jax.random.key(0))
    bad = p.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        hgjax.resample(bad, 0.2, method=method, key=jax.random.key(0))
    with pytest.raises(ValueError, match="shape"):
        hgjax.resample(p[:, :2], 0.2, method=method, key=jax.random.key(0))
    with pytest.raises(TypeError, match="dtype"):
        hgjax.resample(p.astype(int), 0.2, method=method, key=jax.random.key(0))


def test_bad_parameters():
    p = uniform_cloud(50)
    cases = [
        (lambda: hgjax.resample(p, 0.2, method="gfr", mode="best"), ValueError, "mode"),
        (lambda: hgjax.neighbourhoods(p, "ea", k=1), ValueError, "k"),
        (lambda: hgjax.neighbourhoods(p, "ea", k=51), ValueError, "k=51"),
        (lambda: hgjax.resample(p, 0.2, method="pca_ac", n_clusters=0), ValueError, "n_clusters"),
        (lambda: hgjax.resample(p, 0.2, method="ea", n_clusters=2), TypeError, "n_clusters"),
        (lambda: hgjax.farthest_point_sample(p, 0.2, start=50), ValueError, "start"),
        (lambda: hgjax.resample(p, 0.2, method="voxel", size=1.0), TypeError, "size"),
    ]
    for call, error, match in cases:
        with pytest.raises(error, match=match):
            call()
