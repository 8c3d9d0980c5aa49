"""search="jax" under jit, vmap and grad with no sizes passed: the host's neighbourhoods for any cloud, or an error."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hgjax
from fixtures import box_union, cloud_families, grid

pytestmark = pytest.mark.full

KNN = ["ea", "lhf", "mss"]


def _host_idx(p, method):
    return np.asarray(hgjax.neighbourhoods(np.asarray(p), method).idx)


@pytest.fixture(scope="module")
def readme_cloud():
    return box_union(20000).astype(np.float32)


@pytest.mark.parametrize("method", KNN + ["hkc", "hkf", "gfr"])
def test_jitted_resample_of_the_readme_cloud_keeps_the_hosts_points(readme_cloud, method):
    extra = {"mode": "top"} if method == "gfr" else {}
    host = hgjax.resample(readme_cloud, 0.2, method=method, **extra)
    got = np.asarray(jax.jit(lambda p: hgjax.resample(p, 0.2, method=method, search="jax", **extra))(readme_cloud))
    np.testing.assert_array_equal(np.sort(got), np.sort(host))


@pytest.mark.parametrize("method", KNN)
def test_one_compiled_build_serves_a_cloud_sixteen_times_denser(method):
    build = jax.jit(lambda p: hgjax.neighbourhoods(p, method, search="jax").idx)
    sparse = box_union(3000).astype(np.float32)
    for p in (sparse, sparse / 16):  # a surface: 16 x 16 times the points per area
        np.testing.assert_array_equal(np.asarray(build(p)), _host_idx(p, method))
    dense = (box_union(3000, seed=1) * np.array([1 / 16, 1, 1])).astype(np.float32)  # one axis squeezed
    np.testing.assert_array_equal(np.asarray(build(dense)), _host_idx(dense, method))
    assert build._cache_size() == 1


def test_vmap_over_clouds_of_different_densities():
    base = [box_union(1500, seed=s).astype(np.float32) for s in (1, 2, 3)]
    clouds = np.stack([base[0], base[1] * 0.05, base[2] * np.array([1.0, 0.02, 1.0], np.float32)])
    idx = jax.jit(jax.vmap(lambda p: hgjax.neighbourhoods(p, "ea", search="jax").idx))(clouds)
    for b in range(3):
        np.testing.assert_array_equal(np.asarray(idx[b]), _host_idx(clouds[b], "ea"), err_msg=str(b))
    weights = jax.jit(jax.vmap(lambda p: hgjax.soft_weights(hgjax.neighbourhoods(p, "ea", search="jax"), 0.2,
                                                             method="ea")))(clouds)
    for b in range(3):
        want = hgjax.soft_weights(hgjax.neighbourhoods(clouds[b], "ea"), 0.2, method="ea")
        np.testing.assert_allclose(np.asarray(weights[b]), np.asarray(want), rtol=1e-5, atol=1e-6)


def test_a_jitted_training_loop_whose_points_crowd_together_stays_exact():
    """Twenty value_and_grad steps squeezing the cloud to 1/16 of its width: each step's neighbourhoods are the
    host's for that step's points (one compile)."""
    p0 = jnp.asarray(box_union(2000, seed=4).astype(np.float32))

    def loss(s):
        pts = p0 * jnp.stack([jnp.exp(s), jnp.float32(1), jnp.float32(1)])[None, :]
        nb = hgjax.neighbourhoods(pts, "ea", search="jax")
        return jnp.sum(hgjax.soft_weights(nb, 0.2, method="ea") * pts[:, 0]), (pts, nb.idx)

    step = jax.jit(jax.value_and_grad(loss, has_aux=True))
    for s in np.linspace(0.0, np.log(1 / 16), 20, dtype=np.float32):
        (value, (pts, idx)), grad = step(s)
        assert np.isfinite(float(value)) and np.isfinite(float(grad))
        np.testing.assert_array_equal(np.asarray(idx), _host_idx(pts, "ea"))
    assert step._cache_size() == 1


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("method", KNN)
def test_quantised_and_lattice_clouds_under_jit(method, dtype):
    rng = np.random.default_rng(5)
    quantised = np.round(box_union(1500, seed=5) * 64) / 64  # binary steps: float32 and float64 hold them exactly
    lattice = grid((12, 12, 3), 0.125, seed=2)
    with jax.enable_x64(dtype == np.float64):
        for p in (quantised.astype(dtype), lattice.astype(dtype) + rng.integers(0, 2, (1, 3))):
            got = jax.jit(lambda q: hgjax.neighbourhoods(q, method, search="jax").idx)(p)
            np.testing.assert_array_equal(np.asarray(got), _host_idx(p, method))


def test_a_2km_tile_under_jit():
    """Patches 10 cm apart in a 2 km x 2 km tile, UTM-sized coordinates, float64."""
    rng = np.random.default_rng(9)
    centres = rng.random((4, 2)) * 2000.0
    patches = [np.c_[c + rng.random((300, 2)) * 2.0, rng.normal(size=300) * 0.01] for c in centres]
    p = np.concatenate(patches) + np.array([700000.0, 5600000.0, 300.0])
    with jax.enable_x64(True):
        got = jax.jit(lambda q: hgjax.neighbourhoods(q, "ea", search="jax").idx)(p)
        np.testing.assert_array_equal(np.asarray(got), _host_idx(p, "ea"))


def test_a_ball_wider_than_its_columns_names_the_capacity_it_needs():
    p = box_union(3000).astype(np.float32)
    build = jax.jit(lambda q: hgjax.neighbourhoods(q, "hkc", variant="reference", search="jax", capacity=8).idx)
    with pytest.raises(jax.errors.JaxRuntimeError, match=r"capacity=\d+"):
        build(p).block_until_ready()
    grad = jax.jit(jax.grad(lambda q: hgjax.soft_score(
        hgjax.neighbourhoods(q, "hkc", variant="reference", search="jax", capacity=8), "hkc",
        variant="reference").sum()))
    with pytest.raises(jax.errors.JaxRuntimeError, match=r"capacity=\d+"):
        grad(p).block_until_ready()


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("method", KNN + ["hkc", "hkf", "gfr"])
def test_resample_its_pieces_and_the_jitted_traced_resample_return_one_array(method, dtype):
    extra = {"mode": "top"} if method == "gfr" else {}
    with jax.enable_x64(dtype == np.float64):
        p = box_union(2500, seed=6).astype(dtype)
        host = np.asarray(hgjax.resample(p, 0.2, method=method, **extra))
        pieces = hgjax.keep(np.asarray(hgjax.score(hgjax.neighbourhoods(p, method), method)), 0.2, method=method,
                            **extra)
        np.testing.assert_array_equal(np.asarray(pieces), host)
        jitted = jax.jit(lambda q: hgjax.resample(q, 0.2, method=method, search="jax", **extra))(p)
        np.testing.assert_array_equal(np.asarray(jitted), host)


EXACT = ["hkc", "hkf", "lhf", "ea", "pca_ac", "mss"]
GFR = pytest.param("gfr", marks=pytest.mark.xfail(strict=True, reason=(
    "GFR is not the same bits by every path: without x64 its traced graph decides a pair whose length equals the"
    " radius up to float64's rounding by float32 pairs (a 1/16-quantised cloud: 16 of 400 rows lack a pair);"
    " its traced score sums moments and flows in the working dtype, the host's exactly in float64 (lattices: equal"
    " scores then differ); in float32 the host's engine and its score of built neighbourhoods differ in the last"
    " bit on decimal lattices")))


def _host_and_jitted(method):
    """(host, jitted): the host's resample of a cloud, and the jitted traced one (PCA-AC, whose Ward
    selection runs on the host: its jitted traced neighbourhoods and score, then the host's keep)."""
    extra = {"mode": "top"} if method == "gfr" else {}

    def host(p):
        return np.asarray(hgjax.resample(p, 0.2, method=method, search="host", **extra))

    if method == "pca_ac":
        scored = jax.jit(lambda q: hgjax.score(hgjax.neighbourhoods(q, method, search="jax"), method))
        return host, lambda p: hgjax.keep(np.asarray(scored(p)), 0.2, method=method)
    resample = jax.jit(lambda q: hgjax.resample(q, 0.2, method=method, search="jax", **extra))
    return host, lambda p: np.asarray(resample(p))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("method", EXACT + [GFR])
def test_every_cloud_family_resamples_to_the_hosts_array_under_jit(method, dtype):
    """Smooth, tied, lattice (binary and decimal spacings), collinear, coplanar and tilted-plane clouds:
    the jitted traced resample, the host's and keep(score(neighbourhoods)) are one array, order included."""
    extra = {"mode": "top"} if method == "gfr" else {}
    host, jitted = _host_and_jitted(method)
    with jax.enable_x64(dtype == np.float64):
        for name, cloud in cloud_families(seed=1).items():
            p = cloud.astype(dtype)
            want = host(p)
            pieces = hgjax.keep(np.asarray(hgjax.score(hgjax.neighbourhoods(p, method), method)), 0.2, method=method,
                                **extra)
            np.testing.assert_array_equal(pieces, want, err_msg=name)
            np.testing.assert_array_equal(jitted(p), want, err_msg=name)


@pytest.mark.parametrize("scale", [1e150, 1e-138])
@pytest.mark.parametrize("method", EXACT + ["gfr"])
def test_clouds_at_the_ends_of_float64_resample_to_the_hosts_array_under_jit(method, scale):
    """x64: a cloud scaled by 1e150 (squared distances near 1e301) or 1e-138 (near 1e-276), far outside float32."""
    host, jitted = _host_and_jitted(method)
    with jax.enable_x64(True):
        p = box_union(300, seed=2) * scale
        np.testing.assert_array_equal(jitted(p), host(p))
