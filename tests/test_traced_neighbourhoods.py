"""search="jax": the k-nearest methods' neighbourhoods and resample in pure JAX, equal to the host's."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hgjax
from fixtures import box_union

KNN = ["ea", "lhf", "mss"]


def _clouds():
    smooth = box_union(1200, seed=3).astype(np.float32)
    rounded = (np.round(smooth * 20) / 20).astype(np.float32)  # many equal distances and duplicates
    return {"smooth": smooth, "rounded": rounded}


@pytest.fixture(scope="module")
def clouds():
    return _clouds()


def _searched(nb) -> dict:
    """The traced search's settings an eager build ended with, to pass back inside jit."""
    params = dict(nb.params)
    return {"cell_capacity": params["cell_capacity"], "cell_edge": params["cell_edge"]}


@pytest.mark.parametrize("method", KNN)
@pytest.mark.parametrize("which", ["smooth", "rounded"])
def test_traced_neighbourhoods_equal_the_host(clouds, method, which):
    p = clouds[which]
    host = hgjax.neighbourhoods(p, method)
    eager = hgjax.neighbourhoods(p, method, search="jax")
    np.testing.assert_array_equal(np.asarray(eager.idx), host.idx)
    np.testing.assert_array_equal(np.asarray(eager.points), np.asarray(host.points))
    jitted = jax.jit(lambda q: hgjax.neighbourhoods(q, method, search="jax", **_searched(eager)))(p)
    assert int(jitted.overflow) == 0
    np.testing.assert_array_equal(np.asarray(jitted.idx), host.idx)
    np.testing.assert_array_equal(np.asarray(jitted.points), np.asarray(host.points))
    np.testing.assert_array_equal(np.asarray(hgjax.score(jitted, method)), np.asarray(hgjax.score(host, method)))


def test_traced_neighbourhoods_equal_the_host_in_float64(clouds):
    with jax.enable_x64(True):
        p = clouds["rounded"].astype(np.float64)
        host = hgjax.neighbourhoods(p, "ea")
        eager = hgjax.neighbourhoods(p, "ea", search="jax")
        jitted = jax.jit(lambda q: hgjax.neighbourhoods(q, "ea", search="jax", **_searched(eager)))(p)
        assert jitted.points.dtype == jnp.float64
        np.testing.assert_array_equal(np.asarray(jitted.idx), host.idx)
        np.testing.assert_array_equal(np.asarray(jitted.points), host.points)


def test_an_overflow_under_jit_is_flagged_and_refused_eagerly(clouds):
    p = clouds["smooth"]
    nb = jax.jit(lambda q: hgjax.neighbourhoods(q, "ea", search="jax", cell_capacity=4))(p)
    assert int(nb.overflow) != 0
    with pytest.raises(ValueError, match="overflowed the traced search's capacity"):
        hgjax.score(nb, "ea")
    grown = hgjax.neighbourhoods(p, "ea", search="jax", cell_capacity=4)  # eagerly it grows
    assert int(grown.overflow) == 0 and dict(grown.params)["cell_capacity"] > 4
    np.testing.assert_array_equal(np.asarray(grown.idx), hgjax.neighbourhoods(p, "ea").idx)


@pytest.mark.parametrize("method", KNN)
def test_jitted_resample_equals_the_host_composition(clouds, method):
    p = clouds["rounded"]
    settings = _searched(hgjax.neighbourhoods(p, method, search="jax"))
    got = jax.jit(lambda q: hgjax.resample(q, 0.2, method=method, search="jax", **settings))(p)
    host = hgjax.keep(np.asarray(hgjax.score(hgjax.neighbourhoods(p, method), method)), 0.2, method=method)
    np.testing.assert_array_equal(np.asarray(got), host)
    assert set(np.asarray(got).tolist()) == set(hgjax.resample(p, 0.2, method=method).tolist())


def test_vmap_over_a_batch_equals_a_loop(clouds):
    batch = np.stack([clouds["smooth"], clouds["smooth"][::-1] + np.float32(0.25)])
    settings = _searched(hgjax.neighbourhoods(batch[1], "ea", search="jax"))
    nbs = jax.vmap(lambda q: hgjax.neighbourhoods(q, "ea", search="jax", **settings))(batch)
    assert not np.asarray(nbs.overflow).any()
    for b in range(2):
        np.testing.assert_array_equal(np.asarray(nbs.idx[b]), hgjax.neighbourhoods(batch[b], "ea").idx)


def test_a_jitted_training_step_rebuilds_neighbourhoods_and_compiles_once(clouds):
    """Points that move every step: the neighbourhoods are rebuilt inside the jitted step."""
    p0 = jnp.asarray(clouds["smooth"])
    settings = _searched(hgjax.neighbourhoods(p0, "ea", search="jax"))
    settings["cell_capacity"] *= 2  # room for the deformation

    def loss(scale):
        pts = p0 * (1 + scale * jnp.array([[0.1, 0.0, 0.0]]))
        nb = hgjax.neighbourhoods(pts, "ea", search="jax", **settings)
        return jnp.sum(hgjax.soft_weights(nb, 0.2, method="ea") * pts[:, 0])

    step = jax.jit(jax.value_and_grad(loss))
    scale = jnp.float32(0.0)
    for _ in range(5):
        value, grad = step(scale)
        assert np.isfinite(float(value)) and np.isfinite(float(grad))
        scale = scale - 0.1 * grad
    assert step._cache_size() == 1


@pytest.mark.parametrize("call", [
    lambda p: hgjax.tiles.resample(p, 0.2, method="ea", tile=1.0, search="jax"),
    lambda p: hgjax.resample(p, 0.2, method="pca_ac", search="jax"),
    lambda p: hgjax.neighbourhoods(p, "hkc", search="jax"),
])
def test_what_the_traced_search_does_not_cover_is_refused(clouds, call):
    with pytest.raises((ValueError, TypeError)):
        call(clouds["smooth"])
