"""resample(), selection, input errors and degenerate clouds for the HGSP methods."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hgjax
from hgjax import _validate

HGSP = ["hkc", "hkf", "lhf"]
SCORES = {
    "hkc": lambda p, **kw: hgjax.scores.hkc(p, **kw),
    "hkf": lambda p, **kw: hgjax.scores.hkf(p, **kw),
    "hkf_reference": lambda p, **kw: hgjax.scores.hkf(p, variant="reference", **kw),
    "lhf": lambda p, **kw: hgjax.scores.lhf(p, ratio=0.2, **kw),
    "lhf_reference": lambda p, **kw: hgjax.scores.lhf(p, ratio=0.2, variant="reference", **kw),
}


def cloud(n=400, seed=0, dtype=np.float64):
    return np.random.default_rng(seed).random((n, 3)).astype(dtype)


@pytest.mark.parametrize("method", HGSP)
@pytest.mark.parametrize("ratio", [0.013, 0.2, 0.7, 1.0])
def test_resample_count_unique_in_range(method, ratio):
    p = cloud()
    idx = hgjax.resample(p, ratio, method=method)
    assert idx.dtype == np.int64
    assert idx.shape == (int(np.ceil(ratio * 400 - 1e-9)),)
    assert len(np.unique(idx)) == len(idx) and idx.min() >= 0 and idx.max() < 400


@pytest.mark.parametrize("method,largest", [("hkc", False), ("hkf", False), ("lhf", True)])
def test_resample_orders_by_priority(method, largest):
    p = cloud()
    params = {"ratio": 0.25} if method == "lhf" else {}
    s = getattr(hgjax.scores, method)(p, **params)
    idx = hgjax.resample(p, 0.25, method=method)
    kept = s[idx]
    assert np.all(np.diff(kept) <= 0) if largest else np.all(np.diff(kept) >= 0)
    rest = np.setdiff1d(np.arange(400), idx)
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
    with pytest.raises(ValueError, match=r"unknown method 'nope'; expected one of \["):
        hgjax.resample(cloud(), 0.2, method="nope")


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
        hgjax.resample(cloud(), ratio)


def test_bad_ratio_type_and_parameters():
    with pytest.raises(TypeError, match="ratio must be a number"):
        hgjax.resample(cloud(), "0.2")
    with pytest.raises(ValueError, match="unknown variant 'paper'"):
        hgjax.scores.hkc(cloud(), variant="paper")
    with pytest.raises(ValueError, match="kernel_size must be odd"):
        hgjax.scores.hkc(cloud(), kernel_size=4)
    with pytest.raises(ValueError, match="d_factor must be a finite number > 0"):
        hgjax.scores.hkf(cloud(), d_factor=-1)
    with pytest.raises(ValueError, match="lengths must be a pair"):
        hgjax.scores.lhf(cloud(), ratio=0.2, lengths=(4,))
    with pytest.raises(ValueError, match=r"lengths\[0\] must be >= 3"):
        hgjax.scores.lhf(cloud(), ratio=0.2, lengths=(2, 8))
    with pytest.raises(ValueError, match="unknown solver"):
        hgjax.scores.lhf_single(cloud(), 8, solver="svd")


def test_too_few_points_for_the_neighbourhood():
    with pytest.raises(ValueError, match="points has 5 point.*LHF with length 12.*at least 12"):
        hgjax.resample(cloud(5), 0.2, method="lhf")
    with pytest.raises(ValueError, match="too few for HKC"):
        hgjax.scores.hkc(cloud(1))


def test_checks_fire_for_jax_arrays_and_under_a_caller_jit_boundary():
    with pytest.raises(ValueError, match="NaN or inf"):
        hgjax.scores.hkc(jnp.full((10, 3), jnp.nan))
    idx = hgjax.resample(jnp.asarray(cloud()), 0.2)
    np.testing.assert_array_equal(idx, hgjax.resample(cloud(), 0.2))


def degenerate_clouds():
    rng = np.random.default_rng(0)
    line = np.outer(np.linspace(0, 1, 60), [1.0, 2.0, 3.0])
    diagonal = np.outer(np.linspace(0, 1, 60), [1.0, 1.0, 1.0])  # row-centred signal is 0
    plane = np.c_[rng.random((80, 2)), np.zeros(80)]
    dup = np.repeat(rng.random((20, 3)), 4, axis=0)
    return {"collinear": line, "diagonal": diagonal, "coplanar": plane, "duplicates": dup,
            "all_equal": np.ones((40, 3)), "two_points": np.array([[0.0, 0, 0], [1, 1, 1]] * 10)}


@pytest.mark.parametrize("cloud_name", sorted(degenerate_clouds()))
@pytest.mark.parametrize("name", sorted(SCORES))
def test_degenerate_clouds_give_no_nan(cloud_name, name, dtype):
    p = degenerate_clouds()[cloud_name].astype(dtype)
    before = p.copy()
    s = SCORES[name](p)
    assert s.shape == (len(p),) and s.dtype == dtype
    assert not np.isnan(s).any()
    if name != "hkc":
        assert np.isfinite(s).all()  # only HKC's beta may be +inf (documented)
    np.testing.assert_array_equal(p, before)


def test_all_equal_points_documented_values():
    p = np.ones((30, 3))
    assert np.isinf(hgjax.scores.hkc(p)).all()  # only the centre voxel: low band is 0
    np.testing.assert_array_equal(hgjax.scores.lhf_single(p, 8), 0.0)
    idx = hgjax.resample(p, 0.2, method="lhf")
    np.testing.assert_array_equal(idx, np.arange(6))  # all tied: stable by index


def test_input_never_modified_and_readonly_input_accepted():
    p = cloud()
    p.flags.writeable = False
    for m in HGSP:
        hgjax.resample(p, 0.3, method=m)
    q = cloud()
    copy = q.copy()
    hgjax.resample(q, 0.3, method="lhf")
    np.testing.assert_array_equal(q, copy)


def test_float64_without_x64_warns_and_keeps_dtype():
    jax.config.update("jax_enable_x64", False)
    try:
        with pytest.warns(hgjax._stream.PrecisionWarning, match="computed in float32"):
            s = hgjax.scores.hkc(cloud(100))
        assert s.dtype == np.float64
    finally:
        jax.config.update("jax_enable_x64", True)
