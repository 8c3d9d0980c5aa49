"""Library contracts: scale-free FPS, EA and PCA-AC, one check of
``scores`` for every method, ``chunk_size`` named, an empty ASCII PCD named."""

import numpy as np
import pytest

import hgjax
from fixtures import box_union, uniform_cloud
from hgjax import io

SCORING = sorted(m for m, e in hgjax.METHODS.items() if isinstance(e, hgjax.Method))


@pytest.fixture(scope="module")
def cloud():
    return box_union(1000)


@pytest.mark.parametrize("backend", ["fpsample", "jax"])
def test_fps_is_scale_free(cloud, backend):
    if backend == "fpsample":
        pytest.importorskip("fpsample")
    want = hgjax.farthest_point_sample(cloud, 0.2, backend=backend)
    for extent in (1e-40, 1e-25, 1e30):
        idx = hgjax.farthest_point_sample(cloud * extent, 0.2, backend=backend)
        assert np.unique(idx).size == 200, extent
        np.testing.assert_array_equal(idx, want)


@pytest.mark.parametrize("method", ["ea", "pca_ac"])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_ea_and_pca_ac_are_scale_free(cloud, method, dtype):
    """The same scores and kept points at every extent the working dtype represents (squares under- or
    overflowing: float64 at 8e-25, 1.2e21 and 1.3e30; float32 at 9e-11 and 7e15); beyond that range
    (hgjax._validate.check_extent) a ValueError naming points, before any work."""
    points = cloud.astype(dtype)
    want = np.asarray(hgjax.score(hgjax.neighbourhoods(points, method), method))
    assert np.isfinite(want).all() and want.max() > 0
    inside, outside = ((-80, 70, 100), ()) if dtype == np.float64 else ((-36, 50), (-80, 100))
    for k in outside:
        with pytest.raises(ValueError, match="points span .* which float32 cannot represent"):
            hgjax.resample(np.ldexp(points, k).astype(dtype), 0.2, method=method)
    for k in inside:
        scaled = np.ldexp(points, k).astype(dtype)
        np.testing.assert_array_equal(np.asarray(hgjax.score(hgjax.neighbourhoods(scaled, method), method)), want)
        np.testing.assert_array_equal(hgjax.resample(scaled, 0.2, method=method, key=None),
                                      hgjax.resample(points, 0.2, method=method))


@pytest.mark.parametrize("method", SCORING)
@pytest.mark.parametrize("scores, error, message", [
    (None, TypeError, "scores must be a float array of shape {shape}; got None"),
    (np.zeros((4, 3)), ValueError, "scores must have shape {shape}; got \\(4, 3\\)"),
    (np.zeros(0), ValueError, "scores must hold at least one score"),
    (np.arange(4), TypeError, "scores must be a float array; got dtype int64"),
    (np.array([0.1, "a"], dtype=object), TypeError, "scores must be a float array; got dtype object"),
    (np.array([0.1, np.nan, 0.3, 0.2]), ValueError, "scores contains NaN at 1 of 4 points"),
])
def test_keep_checks_scores_the_same_way_for_every_method(method, scores, error, message):
    """(N,) scores, or (N, C) for a method whose score has C columns (LHF's two lengths)."""
    import jax

    columns = hgjax.METHODS[method].columns
    if columns is not None and scores is not None and scores.ndim == 1:
        scores = np.repeat(scores[:, None], columns, axis=1)
    shape = "\\(N,\\)" if columns is None else f"\\(N, {columns}\\)"
    with pytest.raises(error, match=message.format(shape=shape)):
        hgjax.keep(scores, 0.5, method=method, key=jax.random.key(0))


@pytest.mark.parametrize("method", SCORING)
def test_keep_takes_a_count_or_a_ratio(method):
    import jax

    columns = hgjax.METHODS[method].columns
    scores = np.random.default_rng(0).random((50,) if columns is None else (50, columns))
    by_count = hgjax.keep(scores, method=method, count=17, key=jax.random.key(0))
    assert by_count.shape == (17,)
    np.testing.assert_array_equal(by_count, hgjax.keep(scores, 0.34, method=method, key=jax.random.key(0)))
    with pytest.raises(TypeError, match="give the ratio or the count kept, one of them"):
        hgjax.keep(scores, 0.34, method=method, count=17, key=jax.random.key(0))
    with pytest.raises(TypeError, match="give the ratio or the count kept, one of them"):
        hgjax.keep(scores, method=method, key=jax.random.key(0))
    with pytest.raises(ValueError, match="count must be at most the 50 scores; got 51"):
        hgjax.keep(scores, method=method, count=51, key=jax.random.key(0))
    with pytest.raises(TypeError, match="count must be an integer"):
        hgjax.keep(scores, method=method, count=2.0, key=jax.random.key(0))


@pytest.mark.parametrize("chunk_size, error", [(0, ValueError), (-5, ValueError), (2.5, TypeError)])
def test_chunk_size_is_named(cloud, chunk_size, error):
    nb = hgjax.neighbourhoods(cloud, "ea")
    with pytest.raises(error, match="chunk_size must be"):
        hgjax.score(nb, "ea", chunk_size=chunk_size)


def test_an_empty_ascii_pcd_is_an_error_naming_the_file(tmp_path):
    pytest.importorskip("pypcd4")
    path = tmp_path / "empty.pcd"
    path.write_text("VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 0\nHEIGHT 1\n"
                    "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 0\nDATA ascii\n")
    with pytest.raises(io.PointCloudReadError, match=f"cannot read {path}: the file holds no points"):
        io.read_points(path)


@pytest.mark.parametrize("call, error, match", [
    (lambda p: hgjax.resample(p, 0.2, method="ea", dedupe="yes"), TypeError, "dedupe must be True or False"),
    (lambda p: hgjax.resample(p, 0.2, method="lhf", tau=-1), ValueError, "tau must be a finite number > 0"),
    (lambda p: hgjax.resample(p, 0.2, method="lhf", lengths=(8, 100000)), ValueError, r"LHF lengths=\(8, 100000\)"),
    (lambda p: hgjax.neighbourhoods(p, "lhf", lengths=(8, 100000)), ValueError, r"LHF lengths=\(8, 100000\)"),
    (lambda p: hgjax.score(None, "ea"), TypeError, "nb must be hgjax.Neighbourhoods"),
])
def test_parameters_are_named_in_their_errors(call, error, match):
    with pytest.raises(error, match=match):
        call(uniform_cloud(100))


@pytest.mark.full
@pytest.mark.parametrize("method", ["hkc", "hkf", "lhf"])
def test_tau_gradient_is_finite_however_small_tau_is(method):
    import jax

    p = uniform_cloud(200).astype(np.float32)
    nb = hgjax.neighbourhoods(p, method)
    for tau in (1e-30, 1e-8, 0.1):
        g = jax.grad(lambda t: hgjax.soft_weights(nb, 0.2, method=method, tau=t).sum())(tau)
        assert np.isfinite(g), (tau, g)


def _dot_precisions(jaxpr) -> list:
    """The precision of every dot_general in a jaxpr and in the jaxprs its equations hold."""
    found = []
    for eqn in jaxpr.eqns:
        if eqn.primitive.name == "dot_general":
            found.append(eqn.params["precision"])
        for value in eqn.params.values():
            for sub in value if isinstance(value, (tuple, list)) else (value,):
                inner = getattr(sub, "jaxpr", sub)
                if hasattr(inner, "eqns"):
                    found += _dot_precisions(inner)
    return found


@pytest.mark.full
@pytest.mark.parametrize("method", SCORING)
def test_every_product_runs_at_full_precision(cloud, method):
    """A GPU may run a default-precision float32 product in TF32: a local frame lost its bits
    on an H100 and moved points across voxel faces. Every product of the scores, soft scores
    and their gradients asks for HIGHEST."""
    import dataclasses

    import jax

    nb = hgjax.neighbourhoods(cloud[:300].astype(np.float32), method)

    def soft_total(points):
        return hgjax.soft_score(dataclasses.replace(nb, points=points), method).sum()

    programs = [jax.make_jaxpr(lambda n: hgjax.score(n, method))(nb),
                jax.make_jaxpr(jax.grad(soft_total))(nb.points)]
    found = [p for program in programs for p in _dot_precisions(program.jaxpr)]
    highest = (jax.lax.Precision.HIGHEST, jax.lax.Precision.HIGHEST)
    assert all(p == highest for p in found), (method, found)
