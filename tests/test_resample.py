"""resample(), selection, input errors and degenerate clouds for the HGSP methods."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hgjax
from fixtures import degenerate_clouds, uniform_cloud
from hgjax import _validate

HGSP = ["hkc", "hkf", "lhf"]
N = 400


def scores_of(points, method, **params):
    """The composition neighbourhoods -> score, as NumPy."""
    return np.asarray(hgjax.score(hgjax.neighbourhoods(points, method, **params), method, **params))


SCORES = {
    "hkc": lambda p, **kw: scores_of(p, "hkc", **kw),
    "hkc_reference": lambda p, **kw: scores_of(p, "hkc", variant="reference", **kw),
    "hkf": lambda p, **kw: scores_of(p, "hkf", **kw),
    "hkf_reference": lambda p, **kw: scores_of(p, "hkf", variant="reference", **kw),
    "lhf": lambda p, **kw: scores_of(p, "lhf", **kw),
    "lhf_reference": lambda p, **kw: scores_of(p, "lhf", variant="reference", **kw),
}


@pytest.mark.parametrize("method", HGSP)
@pytest.mark.parametrize("ratio", [0.013, 0.2, 0.7, 1.0])
def test_resample_count_unique_in_range(method, ratio):
    p = uniform_cloud(N)
    idx = hgjax.resample(p, ratio, method=method)
    assert idx.dtype == np.int64
    assert idx.shape == (int(np.ceil(ratio * N - 1e-9)),)
    assert len(np.unique(idx)) == len(idx) and idx.min() >= 0 and idx.max() < N


@pytest.mark.parametrize("method,largest", [("hkc", False), ("hkf", False), ("lhf", True)])
def test_resample_orders_by_priority(method, largest):
    p = uniform_cloud(N)
    s = scores_of(p, method)
    if method == "lhf":  # ranked by the two lengths' combination at the kept count (Eqs. (15)-(16))
        s = hgjax.scores.lhf.combine(s, _validate.n_keep(N, 0.25))
    idx = hgjax.resample(p, 0.25, method=method)
    kept = s[idx]
    assert np.all(np.diff(kept) <= 0) if largest else np.all(np.diff(kept) >= 0)
    rest = np.setdiff1d(np.arange(N), idx)
    assert (s[rest] <= kept[-1]).all() if largest else (s[rest] >= kept[-1]).all()


def test_top_k_breaks_ties_by_index():
    s = np.array([1.0, 3.0, 3.0, 3.0, 0.0, 3.0])
    np.testing.assert_array_equal(hgjax.top_k(s, 3), [1, 2, 3])
    np.testing.assert_array_equal(hgjax.top_k(np.zeros(5), 2, largest=False), [0, 1])
    inf = np.array([np.inf, 1.0, np.inf, 0.5])
    np.testing.assert_array_equal(hgjax.top_k(inf, 4, largest=False), [3, 1, 0, 2])


def test_n_keep_is_ceil_without_float_surprises():
    assert _validate.n_keep(10, 0.7) == 7
    assert _validate.n_keep(10, 0.71) == 8
    assert _validate.n_keep(3, 1e-6) == 1


def test_methods_registry_and_unknown_method():
    assert {"hkc", "hkf", "lhf"} <= set(hgjax.METHODS)
    for name, entry in hgjax.METHODS.items():
        assert isinstance(entry, (hgjax.Method, hgjax.Sampler)) and entry.name == name
    assert sorted(m for m, e in hgjax.METHODS.items() if isinstance(e, hgjax.Sampler)) == ["fps", "uniform", "voxel"]
    assert [hgjax.METHODS[m].largest for m in HGSP] == [False, False, True]
    with pytest.raises(ValueError, match=r"unknown method 'nope'; expected one of \["):
        hgjax.resample(uniform_cloud(N), 0.2, method="nope")
    with pytest.raises(ValueError, match="sampler without scores"):
        hgjax.neighbourhoods(uniform_cloud(N), "fps")
    with pytest.raises(TypeError, match=r"unexpected parameter\(s\) \['foo'\]"):
        hgjax.resample(uniform_cloud(N), 0.2, method="hkc", foo=1)


@pytest.mark.parametrize("method", HGSP)
def test_resample_is_keep_of_score_of_neighbourhoods(method):
    p = uniform_cloud(N, seed=3)
    nb = hgjax.neighbourhoods(p, method)
    assert nb.idx.dtype == np.int32 and nb.points.shape == (N, 3)
    s = hgjax.score(nb, method)
    np.testing.assert_array_equal(hgjax.keep(s, 0.2, method=method), hgjax.resample(p, 0.2, method=method))
    entry = hgjax.METHODS[method]
    ranked = np.asarray(s) if entry.combine is None else entry.combine(np.asarray(s), 80)
    np.testing.assert_array_equal(hgjax.top_k(ranked, 80, largest=entry.largest), hgjax.keep(s, 0.2, method=method))


@pytest.mark.parametrize("name", sorted(SCORES))
def test_scores_follow_a_permutation_of_the_input(name):
    p = uniform_cloud(300, seed=4)
    perm = np.random.default_rng(5).permutation(len(p))
    np.testing.assert_array_equal(SCORES[name](p[perm]), SCORES[name](p)[perm])


@pytest.mark.parametrize("method", HGSP)
def test_resample_does_not_depend_on_input_order(method):
    p = uniform_cloud(300, seed=6)
    perm = np.random.default_rng(7).permutation(len(p))
    a, b = hgjax.resample(p, 0.2, method=method), hgjax.resample(p[perm], 0.2, method=method)
    assert set(perm[b].tolist()) == set(a.tolist())


@pytest.mark.parametrize(
    "bad,exc,match",
    [
        (np.zeros((10, 2)), ValueError, r"points must have shape \(N, 3\); got \(10, 2\)"),
        (np.zeros(30), ValueError, r"shape \(N, 3\)"),
        (np.zeros((2, 10, 3)), ValueError, r"shape \(N, 3\)"),
        (np.zeros((0, 3)), ValueError, "at least one point"),
        (np.zeros((10, 3), dtype=np.int64), TypeError, "float32 or float64; got int64"),
        (np.zeros((10, 3), dtype=np.float16), TypeError, "got float16"),
        (np.array([[0, 0, np.nan]] + [[1.0, 2, 3]] * 9), ValueError, "NaN or inf"),
        (np.array([[0, 0, np.inf]] + [[1.0, 2, 3]] * 9), ValueError, "NaN or inf"),
    ],
)
@pytest.mark.parametrize("method", HGSP)
def test_bad_points_raise_clear_errors(bad, exc, match, method):
    with pytest.raises(exc, match=match):
        hgjax.resample(bad, 0.2, method=method)


@pytest.mark.parametrize("ratio", [0, -0.1, 1.5, float("nan")])
def test_bad_ratio(ratio):
    with pytest.raises(ValueError, match="ratio must be in"):
        hgjax.resample(uniform_cloud(N), ratio)


def test_bad_ratio_type_and_parameters():
    with pytest.raises(TypeError, match="ratio must be a number"):
        hgjax.resample(uniform_cloud(N), "0.2")
    with pytest.raises(ValueError, match="unknown variant 'paper'"):
        hgjax.resample(uniform_cloud(N), 0.2, method="hkc", variant="paper")
    with pytest.raises(ValueError, match="kernel_size must be odd"):
        hgjax.neighbourhoods(uniform_cloud(N), "hkc", kernel_size=4)
    with pytest.raises(ValueError, match="kernel_size must be odd"):
        hgjax.score(hgjax.neighbourhoods(uniform_cloud(N), "hkc"), "hkc", kernel_size=4)
    with pytest.raises(ValueError, match="d_factor must be a finite number > 0"):
        hgjax.neighbourhoods(uniform_cloud(N), "hkf", d_factor=-1)
    with pytest.raises(ValueError, match="lengths must be a pair"):
        hgjax.resample(uniform_cloud(N), 0.2, method="lhf", lengths=(4,))
    with pytest.raises(ValueError, match=r"lengths\[0\] must be >= 3"):
        hgjax.neighbourhoods(uniform_cloud(N), "lhf", lengths=(2, 8))
    with pytest.raises(ValueError, match="unknown solver"):
        hgjax.scores.lhf.single(hgjax.neighbourhoods(uniform_cloud(N), "lhf"), lengths=(8,), solver="svd")
    with pytest.raises(ValueError, match="needs nb.scale"):
        hgjax.score(hgjax.knn(uniform_cloud(N), 8), "hkc")
    k = max(hgjax.scores.lhf.DEFAULT_LENGTHS)  # the default lengths need k > 8 columns
    with pytest.raises(ValueError, match=f"8 columns, too few for LHF with length {k}"):
        hgjax.score(hgjax.knn(uniform_cloud(N), 8), "lhf")


def test_too_few_points_for_the_neighbourhood():
    k = max(hgjax.scores.lhf.DEFAULT_LENGTHS)
    with pytest.raises(ValueError, match=rf"points has 5 point.*LHF lengths=\(8, {k}\).*at least {k}"):
        hgjax.resample(uniform_cloud(5), 0.2, method="lhf")
    with pytest.raises(ValueError, match="too few for HKC"):
        hgjax.neighbourhoods(uniform_cloud(1), "hkc")


def test_checks_fire_for_jax_arrays_and_under_a_caller_jit_boundary():
    with pytest.raises(ValueError, match="NaN or inf"):
        hgjax.neighbourhoods(jnp.full((10, 3), jnp.nan), "hkc")
    idx = hgjax.resample(jnp.asarray(uniform_cloud(N)), 0.2)
    np.testing.assert_array_equal(idx, hgjax.resample(uniform_cloud(N), 0.2))


@pytest.mark.full
@pytest.mark.parametrize("cloud_name", sorted(degenerate_clouds()))
@pytest.mark.parametrize("name", sorted(SCORES))
def test_degenerate_clouds_give_no_nan(cloud_name, name, dtype):
    p = degenerate_clouds()[cloud_name].astype(dtype)
    before = p.copy()
    s = SCORES[name](p)
    assert s.shape == ((len(p), 2) if name.startswith("lhf") else (len(p),)) and s.dtype == dtype
    assert not np.isnan(s).any()
    if not name.startswith("hkc"):
        assert np.isfinite(s).all()  # only HKC's beta may be +inf (documented)
    np.testing.assert_array_equal(p, before)


def test_all_equal_points_documented_values():
    p = np.ones((30, 3))
    assert np.isinf(scores_of(p, "hkc")).all()  # only the centre voxel: low band is 0
    assert np.isinf(scores_of(p, "hkc", variant="reference")).all()
    for variant in ("invariant", "reference"):
        nb = hgjax.neighbourhoods(p, "lhf", variant=variant)
        np.testing.assert_array_equal(hgjax.scores.lhf.single(nb, lengths=(8,), variant=variant), 0.0)
    idx = hgjax.resample(p, 0.2, method="lhf")
    np.testing.assert_array_equal(idx, np.arange(6))  # all tied: stable by index


def test_input_never_modified_and_readonly_input_accepted():
    p = uniform_cloud(N)
    p.flags.writeable = False
    for m in HGSP:
        hgjax.resample(p, 0.3, method=m)
    q = uniform_cloud(N)
    copy = q.copy()
    hgjax.resample(q, 0.3, method="lhf")
    np.testing.assert_array_equal(q, copy)


def test_float64_without_x64_computes_in_float32():
    # a unit cloud loses nothing it holds in float32: no PrecisionWarning (tests/test_precision.py warns)
    jax.config.update("jax_enable_x64", False)
    try:
        nb = hgjax.neighbourhoods(uniform_cloud(100), "hkc")
        assert nb.points.dtype == np.float32 and nb.scale.dtype == np.float32
        assert hgjax.score(nb, "hkc").dtype == np.float32
        idx = hgjax.resample(uniform_cloud(100), 0.2, method="hkc")
        assert len(np.unique(idx)) == 20
    finally:
        jax.config.update("jax_enable_x64", True)
