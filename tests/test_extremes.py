"""Extreme coordinates and refused parameters: a right result or a clear
ValueError naming the argument and the accepted range, raised before any work; never a crash,
a hang, NaN scores or a repeated index.

The rule (hgjax._validate.check_extent): the dtype the geometry is computed in represents a
cloud whose extent E (its widest axis) is 0 or has finite squared distances (E^2 <= max / 2^16)
and a resolved spacing whose square is normal ((eps E)^2 >= tiny): E in about [9.1e-13, 7.2e16]
in float32 (float64 input while x64 is off included) and [6.7e-139, 5.2e151] in float64.
Inside it every method is scale-invariant: a cloud scaled by a power of two keeps the same points.
"""

import warnings

import jax
import numpy as np
import pytest

import hgjax
from hgjax import _validate

KEY = jax.random.key(0)
SCORING = sorted(m for m, e in hgjax.METHODS.items() if isinstance(e, hgjax.Method))


@pytest.fixture(scope="module")
def cloud():
    """B(200): box_union_cloud(seed=0, n_points=200), extent 6 (float64)."""
    return hgjax.eval.box_union_cloud(seed=0, n_points=200).points


def _resample(points, method, **params):
    """``hgjax.resample`` with x64 as set by the caller, float64 input's PrecisionWarning silenced."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", hgjax.PrecisionWarning)
        return hgjax.resample(points, 0.2, method=method, key=KEY, **params)


def _same(got, want):
    """The same kept points (ties of equal scores may come in another order)."""
    assert sorted(got.tolist()) == sorted(want.tolist())


def _refused(points, method, match, **params):
    """The ValueError naming ``points``, raised before any stage of the run ends."""
    stages = []
    with pytest.raises(ValueError, match=match):
        _resample(points, method, on_stage=lambda name, seconds: stages.append(name), **params)
    assert stages == []


def test_extent_range():
    assert _validate.extent_range(np.float32) == pytest.approx((9.09e-13, 7.21e16), rel=1e-3)
    assert _validate.extent_range(np.float64) == pytest.approx((6.72e-139, 5.24e151), rel=1e-3)
    assert _validate.check_extent(np.zeros(3), np.zeros(3), np.float32) == 0.0  # every point equal
    with pytest.raises(ValueError, match=r"points span 1e\+17 .* overflow; the extent must be 0 or in \[9.1e-13, 7.2e\+16\]"):
        _validate.check_extent(np.zeros(3), np.array([1e17, 0, 0]), np.float32)
    with pytest.raises(ValueError, match=r"span more than float64 holds"):
        _validate.check_extent(np.array([-1.7e308, 0, 0]), np.array([1.7e308, 0, 0]), np.float64)


# ------------------------------------------------------------------------------------------ GFR
def test_gfr_beyond_float32_is_refused(cloud):
    # was: OverflowError: cannot convert float infinity to integer (B(800) x 1e19, x64 off)
    with jax.enable_x64(False):
        _refused(cloud * 1e19, "gfr", r"points span 6e\+19 .* float32 .*jax_enable_x64")
        _refused(cloud.astype(np.float32) * np.float32(1e19), "gfr", r"float32 cannot represent")
        _same(_resample(cloud * 2.0**53, "gfr", mode="top"), _resample(cloud, "gfr", mode="top"))  # extent 5.4e16


@pytest.mark.parametrize("scale", [2.0**500, 2.0**-332, 2.0**-432])  # about 3e150, 1e-100, 9e-131
def test_gfr_float64_squares_beyond_float64(cloud, scale):
    # q^2 over- or underflows float64 here (was: NaN to int at 1e150); the moments are scaled exactly
    with jax.enable_x64(True):
        _same(_resample(cloud * scale, "gfr", mode="top"), _resample(cloud, "gfr", mode="top"))
        _same(_resample(cloud * scale, "gfr"), _resample(cloud, "gfr"))


def test_gfr_spacing_underflow_is_refused(cloud):
    # was: ZeroDivisionError (B(800) x 1e-150, x64 on)
    with jax.enable_x64(True):
        _refused(cloud * 1e-150, "gfr", r"points span 6e-150 .* float64 .* underflow .* \[6.7e-139, 5.2e\+151\]")


def test_keep_takes_infinite_scores_alike():
    # gfr's random mode raised OverflowError on +inf, PCA-AC's keep refused it: now every
    # method's keep takes +inf (check_scores: NaN is the only refused value)
    rng = np.random.default_rng(0)
    scores = rng.random(20)
    scores[[3, 7]] = np.inf
    for method in SCORING:
        columns = hgjax.METHODS[method].columns  # LHF: two columns (Eq. (16) weighs them)
        for count in (2, 5):
            idx = hgjax.keep(scores if columns is None else np.stack([scores, scores[::-1]], axis=1), count=count,
                             method=method, key=KEY)
            assert len(set(idx.tolist())) == count and idx.min() >= 0 and idx.max() < 20
    np.testing.assert_array_equal(hgjax.keep(scores, count=5, method="pca_ac"), hgjax.keep(scores, count=5, method="ea"))
    assert set(hgjax.keep(scores, count=2, method="gfr", mode="top").tolist()) == {3, 7}
    scores[0] = -np.inf
    np.testing.assert_array_equal(hgjax.keep(scores, count=20, method="pca_ac"), hgjax.keep(scores, count=20, method="ea"))
    assert hgjax.keep(np.stack([scores, scores], axis=1), count=2, method="lhf").tolist() == [3, 7]
    both = np.stack([rng.random(20), rng.random(20)], axis=1)
    both[3] = np.inf, -np.inf  # both columns weighted (0 < eps < 1): no rank
    with pytest.raises(ValueError, match="scores holds \\+inf and -inf in one row"):
        hgjax.keep(both, count=5, method="lhf")


def test_gfr_random_weights_of_infinite_and_huge_scores():
    # pi's limit: the c infinite scores share 0.8 (0.8 / c + 0.2 / N each), the others 0.2 / N
    scores = np.array([1.0, np.inf, 2.0, np.inf, 0.0])
    weights = np.where(np.isinf(scores), 0.8 / 2, 0.0) + 0.2 / 5
    np.testing.assert_array_equal(hgjax.keep(scores, count=3, method="gfr", key=KEY),
                                  hgjax.engine.select.weighted_sample(KEY, weights, 3))
    huge = np.array([1e308, 1e308, 1.0, 0.0])  # a sum beyond float64: pi = (0.4 + 0.05, 0.45, 0.05, 0.05)
    np.testing.assert_array_equal(hgjax.keep(huge, count=2, method="gfr", key=KEY),
                                  hgjax.engine.select.weighted_sample(KEY, np.array([0.45, 0.45, 0.05, 0.05]), 2))
    with pytest.raises(ValueError, match=r"scores must be >= 0 .* got -1.0"):
        hgjax.keep(np.array([1.0, -1.0]), count=1, method="gfr", key=KEY)


# ------------------------------------------------------------------------------------ MSS, HKC
def test_mss_beyond_float32_is_refused_and_right_in_float64(cloud):
    # was: 800 NaN scores and indices without an error (B(800) x 1e150, x64 off)
    with jax.enable_x64(False):
        _refused(cloud * 1e150, "mss", r"points span 6e\+150 .* float32")
    with jax.enable_x64(True):
        _same(_resample(cloud * 2.0**500, "mss"), _resample(cloud, "mss"))


def test_hkc_beyond_float64_squares_is_refused(cloud):
    # was: IndexError: index 800 is out of bounds (the k-d tree's squared distances overflow)
    with jax.enable_x64(True):
        _refused(cloud * 1e155, "hkc", r"points span 6e\+155 .* float64 .* overflow")
        with pytest.raises(ValueError, match="points span 6e\\+155"):
            hgjax.tiles.resample(cloud * 1e155, 0.2, method="hkc", tile=1e155)
        with pytest.raises(ValueError, match="points span"):
            hgjax.neighbourhoods(cloud * 1e155, "hkc")
        _same(_resample(cloud * 2.0**500, "hkc"), _resample(cloud, "hkc"))


@pytest.mark.parametrize("method", SCORING)
def test_every_method_at_the_ends_of_the_float32_range(cloud, method):
    p = cloud.astype(np.float32)
    with jax.enable_x64(False):
        want = _resample(p, method)
        for scale in (2.0**-40, 2.0**53):  # extents 5.5e-12 and 5.4e16: inside
            _same(_resample(p * np.float32(scale), method), want)
        for scale in (2.0**-43, 2.0**54):  # extents 6.8e-13 and 1.1e17: outside
            _refused(p * np.float32(scale), method, r"points span .* float32 cannot represent")


# ------------------------------------------------------------------------------------- samplers
def test_voxel_beyond_float64_squares_is_refused(cloud):
    # was: 156 duplicates of 160 (B(800) x 1e200); the sampler computes in float64 on the host
    for x64 in (False, True):
        with jax.enable_x64(x64):
            _refused(cloud * 1e200, "voxel", r"points span 6e\+200 .* float64")
            with pytest.raises(ValueError, match="points span"):
                hgjax.voxel_sample(cloud * 1e200, 0.2)


def test_voxel_near_the_largest_float64():
    # was: a hang when the extent overflows float64, and repeated indices where the centroid sums did
    p = hgjax.eval.box_union_cloud(seed=0, n_points=800).points
    line = p * [0.0, 0.0, 1.0]  # x and y vanish next to 1.7e308: the cloud is this line of z values
    want = hgjax.voxel_sample(line, 0.2)
    far = p + np.array([1.7e308, -1.7e308, 0.0])
    np.testing.assert_array_equal(hgjax.voxel_sample(far, 0.2), want)
    np.testing.assert_array_equal(hgjax.tiles.resample(far, 0.2, method="voxel", tile=1.0), want)
    assert len(set(want.tolist())) == want.size == 160
    wide = np.array([[-1.7e308, 0.0, 0.0], [1.7e308, 0.0, 0.0], [0.0, 1.0, 0.0]])
    _refused(wide, "voxel", r"points span more than float64 holds")
    _refused(wide, "fps", r"points span more than float64 holds")


def test_fps_far_outlier():
    # fpsample's float32 squares of the unit spacing underflow next to 1e30: it returned [0, 4, 4, 4, 1]
    p = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1e30, 0, 0]], dtype=np.float64)
    with jax.enable_x64(True):
        jax_path = hgjax.resample(p, 1.0, method="fps", backend="jax")
        assert sorted(jax_path.tolist()) == [0, 1, 2, 3, 4]
        if hgjax.fps_backend("auto") == "fpsample":
            np.testing.assert_array_equal(hgjax.resample(p, 1.0, method="fps", backend="fpsample"), jax_path)
    with jax.enable_x64(False):  # float32 squares of an extent of 1e30 overflow
        _refused(p, "fps", r"points span 1e\+30 .* float32")


def test_fps_keeps_points_that_float32_makes_one():
    # next to 1e15 the unit-spaced points are one in float32: fpsample took them in its tree's order ([0, 4, 2, 3, 1])
    p = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1e15, 0, 0]], dtype=np.float64)
    with jax.enable_x64(True):
        np.testing.assert_array_equal(hgjax.resample(p, 1.0, method="fps", backend="jax"), [0, 4, 1, 2, 3])
        if hgjax.fps_backend("auto") == "fpsample":
            np.testing.assert_array_equal(hgjax.resample(p, 1.0, method="fps", backend="fpsample"), [0, 4, 1, 2, 3])


# ----------------------------------------------------------------------------------- parameters
@pytest.mark.parametrize("method", SCORING)
def test_resample_refuses_what_neighbourhoods_refuses(cloud, method):
    runs = [lambda value: _resample(cloud, method, capacity=value)]
    if method != "pca_ac":  # PCA-AC refuses tiles
        runs.append(lambda value: hgjax.tiles.resample(cloud, 0.2, method=method, key=KEY, tile=2.0, capacity=value))
    for value in (0, -5, 2.5):
        with pytest.raises((TypeError, ValueError), match="capacity") as built:
            hgjax.neighbourhoods(cloud, method, capacity=value)
        for run in runs:
            with pytest.raises(built.type, match=f"^{built.value}$"):
                run(value)
    for value in ("yes", 1):
        with pytest.raises(TypeError, match=f"progress must be True or False; got {value!r}"):
            _resample(cloud, method, progress=value)
    if method == "gfr":  # the reference graph runs on the whole cloud at once
        with pytest.raises(TypeError, match="progress"):
            _resample(cloud, method, variant="reference", progress="yes")


def test_pca_ac_n_clusters_range(cloud):
    with pytest.raises(ValueError, match=r"n_clusters must be in \[1, N\] = \[1, 200\] for N = 200 points; got 1000000000"):
        _resample(cloud, "pca_ac", n_clusters=10**9)
    with pytest.raises(ValueError, match=r"n_clusters must be in \[1, N\] = \[1, 3\]"):
        hgjax.keep(np.array([0.1, 0.2, 0.3]), count=1, method="pca_ac", n_clusters=4)
    assert hgjax.keep(np.array([0.3]), count=1, method="pca_ac").tolist() == [0]  # the default 2, capped at N = 1
    assert len(_resample(cloud, "pca_ac", n_clusters=200)) == 40
