"""search="jax": the k-nearest methods' and HKC/HKF's neighbourhoods and resample in pure JAX, equal to the host's."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hgjax
from fixtures import degenerate_clouds, smooth_and_rounded

pytestmark = pytest.mark.full

KNN = ["ea", "lhf", "mss"]
CUBE = ["hkc", "hkf"]  # balls.build: the invariant ball or the reference cube, and the voxel spacing


@pytest.fixture(scope="module")
def clouds():
    return smooth_and_rounded()


@pytest.mark.parametrize("method", KNN)
@pytest.mark.parametrize("which", ["smooth", "rounded"])
def test_traced_neighbourhoods_equal_the_host(clouds, method, which):
    p = clouds[which]
    host = hgjax.neighbourhoods(p, method)
    eager = hgjax.neighbourhoods(p, method, search="jax")
    np.testing.assert_array_equal(np.asarray(eager.idx), host.idx)
    np.testing.assert_array_equal(np.asarray(eager.points), np.asarray(host.points))
    jitted = jax.jit(lambda q: hgjax.neighbourhoods(q, method, search="jax"))(p)
    assert int(jitted.overflow) == 0
    np.testing.assert_array_equal(np.asarray(jitted.idx), host.idx)
    np.testing.assert_array_equal(np.asarray(jitted.points), np.asarray(host.points))
    np.testing.assert_array_equal(np.asarray(hgjax.score(jitted, method)), np.asarray(hgjax.score(host, method)))


def test_traced_neighbourhoods_equal_the_host_in_float64(clouds):
    with jax.enable_x64(True):
        p = clouds["rounded"].astype(np.float64)
        host = hgjax.neighbourhoods(p, "ea")
        eager = hgjax.neighbourhoods(p, "ea", search="jax")
        jitted = jax.jit(lambda q: hgjax.neighbourhoods(q, "ea", search="jax"))(p)
        assert jitted.points.dtype == jnp.float64
        np.testing.assert_array_equal(np.asarray(eager.idx), host.idx)
        np.testing.assert_array_equal(np.asarray(jitted.idx), host.idx)
        np.testing.assert_array_equal(np.asarray(jitted.points), host.points)


def test_few_slots_under_jit_still_read_every_candidate(clouds):
    p = clouds["smooth"]
    nb = jax.jit(lambda q: hgjax.neighbourhoods(q, "ea", search="jax", cell_slots=4))(p)
    assert int(nb.overflow) == 0
    np.testing.assert_array_equal(np.asarray(nb.idx), hgjax.neighbourhoods(p, "ea").idx)


@pytest.mark.parametrize("method", KNN)
def test_jitted_resample_equals_the_host_composition(clouds, method):
    p = clouds["rounded"]
    got = jax.jit(lambda q: hgjax.resample(q, 0.2, method=method, search="jax"))(p)
    host = hgjax.keep(np.asarray(hgjax.score(hgjax.neighbourhoods(p, method), method)), 0.2, method=method)
    np.testing.assert_array_equal(np.asarray(got), host)
    assert set(np.asarray(got).tolist()) == set(hgjax.resample(p, 0.2, method=method).tolist())


def test_vmap_over_a_batch_equals_a_loop(clouds):
    batch = np.stack([clouds["smooth"], clouds["smooth"][::-1] + np.float32(0.25)])
    nbs = jax.vmap(lambda q: hgjax.neighbourhoods(q, "ea", search="jax"))(batch)
    assert not np.asarray(nbs.overflow).any()
    for b in range(2):
        np.testing.assert_array_equal(np.asarray(nbs.idx[b]), hgjax.neighbourhoods(batch[b], "ea").idx)


def test_a_jitted_training_step_rebuilds_neighbourhoods_and_compiles_once(clouds):
    """Points that move every step: the neighbourhoods are rebuilt inside the jitted step."""
    p0 = jnp.asarray(clouds["smooth"])

    def loss(scale):
        pts = p0 * (1 + scale * jnp.array([[0.1, 0.0, 0.0]]))
        nb = hgjax.neighbourhoods(pts, "ea", search="jax")
        return jnp.sum(hgjax.soft_weights(nb, 0.2, method="ea") * pts[:, 0])

    step = jax.jit(jax.value_and_grad(loss))
    scale = jnp.float32(0.0)
    for _ in range(5):
        value, grad = step(scale)
        assert np.isfinite(float(value)) and np.isfinite(float(grad))
        scale = scale - 0.1 * grad
    assert step._cache_size() == 1


@pytest.mark.parametrize("call", [
    lambda p: hgjax.resample(p, 0.2, method="pca_ac", traced=True),
    lambda p: hgjax.resample(p, 0.2, method="gfr", traced=True),
])
def test_what_the_traced_search_does_not_cover_is_refused(clouds, call):
    with pytest.raises((ValueError, TypeError)):
        call(clouds["smooth"])


# ----------------------------------------------------------------------------- HKC/HKF: cubes and balls
@functools.lru_cache(maxsize=None)
def _jitted_cubes(variant: str, cell_slots: int, capacity: int):
    """One jitted HKC build per static setting (the edge traced), shared by the clouds that need it."""
    return jax.jit(lambda q, edge: hgjax.neighbourhoods(q, "hkc", variant=variant, search="jax", cell_edge=edge,
                                                        cell_slots=cell_slots, capacity=capacity))


def _jitted_like(nb, p, variant="invariant"):
    return _jitted_cubes(variant, 8, nb.idx.shape[-1])(p, None)


@pytest.fixture(scope="module")
def cube_builds(clouds):
    """(host, eager traced) HKC neighbourhoods by (cloud, variant), built once."""
    cache = {}

    def get(which, variant):
        if (which, variant) not in cache:
            p = clouds[which]
            cache[which, variant] = (hgjax.neighbourhoods(p, "hkc", variant=variant),
                                     hgjax.neighbourhoods(p, "hkc", variant=variant, search="jax"))
        return cache[which, variant]
    return get


def _assert_same_cubes(got, host):
    np.testing.assert_array_equal(np.asarray(got.idx), host.idx)
    np.testing.assert_array_equal(np.asarray(got.points), np.asarray(host.points))
    np.testing.assert_array_equal(np.asarray(got.scale), np.asarray(host.scale))


@pytest.mark.parametrize("variant", ["invariant", "reference"])
@pytest.mark.parametrize("which", ["smooth", "rounded"])
def test_traced_cubes_equal_the_host(clouds, cube_builds, variant, which):
    """The whole build traced: spacing (or resolution), d factor from the sample, ball (or cube), scale d."""
    host, eager = cube_builds(which, variant)
    _assert_same_cubes(eager, host)
    jitted = _jitted_like(eager, clouds[which], variant)
    assert int(jitted.overflow) == 0
    _assert_same_cubes(jitted, host)
    np.testing.assert_array_equal(np.asarray(hgjax.score(jitted, "hkc", variant=variant)),
                                  np.asarray(hgjax.score(host, "hkc", variant=variant)))


def test_traced_cubes_equal_the_host_in_float64(clouds):
    with jax.enable_x64(True):
        p = clouds["rounded"].astype(np.float64)
        eager = hgjax.neighbourhoods(p, "hkc", search="jax")
        assert eager.points.dtype == jnp.float64 and eager.scale.dtype == jnp.float64
        _assert_same_cubes(eager, hgjax.neighbourhoods(p, "hkc"))


@pytest.mark.parametrize("variant", ["invariant", "reference"])
def test_traced_cubes_in_float32_pairs_are_the_same_under_jit(clouds, variant):
    """Without x64 the spacing, d factor and scale are float32 pairs: jitted (where XLA fuses a product
    by a constant into a later addition unless :func:`hgjax._exact.mul` hides it) as eagerly, the host's."""
    with jax.enable_x64(False):
        p = clouds["smooth"]
        host = hgjax.neighbourhoods(p, "hkc", variant=variant)
        eager = hgjax.neighbourhoods(p, "hkc", variant=variant, search="jax")
        _assert_same_cubes(eager, host)
        jitted = _jitted_like(eager, p, variant)
        assert jitted.scale.dtype == jnp.float32 and int(jitted.overflow) == 0
        _assert_same_cubes(jitted, host)


@pytest.mark.parametrize("variant", ["invariant", "reference"])
def test_a_point_between_the_float32_radius_and_the_hosts_is_listed_as_the_host_lists_it(variant):
    """Without x64 the radius stays a float32 pair: a point whose distance lies above the radius rounded
    to float32 but below the host's float64 radius is inside both balls (1 row of 1e6 on the box surface
    was short of it when the radius was rounded)."""
    widen = np.sqrt(3.0) if variant == "invariant" else 1.0
    half = widen * 3 / 2 * 1.3 * 0.1  # the host's float64 radius: widen x k / 2 x d_factor x resolution
    below = np.float32(half)
    if float(below) > half:
        below = np.nextafter(below, np.float32(0))
    gap = np.float32((half - float(below)) / 2)  # the query at -gap, the point at `below`: in between
    p = np.array([[-gap, 0, 0], [below, 0, 0], [5, 5, 5], [6, 5, 5]], np.float32)
    params = {"variant": variant, "resolution": 0.1, "d_factor": 1.3}
    with jax.enable_x64(False):
        host = hgjax.neighbourhoods(p, "hkc", **params)
        assert host.idx[0, 1] == 1  # inside the host's ball, by construction
        _assert_same_cubes(hgjax.neighbourhoods(p, "hkc", search="jax", **params), host)


@pytest.mark.parametrize("params", [{"resolution": 0.1}, {"variant": "reference", "resolution": 0.1, "d_factor": 1.5}],
                         ids=["resolution", "both"])
def test_traced_cubes_with_a_fixed_resolution_and_factor(clouds, params):
    p = clouds["rounded"]
    _assert_same_cubes(hgjax.neighbourhoods(p, "hkc", search="jax", **params), hgjax.neighbourhoods(p, "hkc", **params))


def test_the_traced_d_factor_ramp_is_the_hosts():
    """The irregularity between the lattice and the random regimes sets d_factor by a linear ramp, same bits."""
    from hgjax.neighbours import balls
    ramp = (balls.IRREGULARITY_RANGE, (balls.REGULAR_D_FACTOR, balls.IRREGULAR_D_FACTOR))
    x = np.array([0.0, 0.25, 0.3, 0.3333, 0.41, 0.45, 0.6])
    with jax.enable_x64(True):
        got = np.asarray(jax.jit(lambda v: balls.linear_ramp(v, ramp))(jnp.asarray(x)))
    np.testing.assert_array_equal(got, [balls.default_d_factor(v) for v in x])


def test_cube_resample_equals_the_host(clouds, cube_builds):
    """Jitted (HKC) and eager (HKF, same cubes) resamples with the traced search keep the host's points."""
    p = clouds["smooth"]
    settings = {"capacity": cube_builds("smooth", "invariant")[1].idx.shape[-1]}
    got = jax.jit(lambda q: hgjax.resample(q, 0.2, method="hkc", search="jax", **settings))(p)
    np.testing.assert_array_equal(np.asarray(got), hgjax.resample(p, 0.2, method="hkc"))
    np.testing.assert_array_equal(np.asarray(hgjax.resample(p, 0.2, method="hkf", search="jax")),
                                  hgjax.resample(p, 0.2, method="hkf"))


def test_a_cube_wider_than_its_columns_under_jit_stops_the_program(clouds):
    p = clouds["smooth"]
    needed = hgjax.neighbourhoods(p, "hkc", variant="reference", search="jax").idx.shape[1]
    with pytest.raises(jax.errors.JaxRuntimeError, match=r"capacity=\d+"):
        _jitted_cubes("reference", 4, 4)(p, None).idx.block_until_ready()
    nb = _jitted_cubes("reference", 4, needed)(p, None)
    assert int(nb.overflow) == 0
    with pytest.raises(ValueError, match="capacity=4 is too small"):  # eagerly, as the host
        hgjax.neighbourhoods(p, "hkc", variant="reference", search="jax", capacity=4)


@pytest.mark.parametrize("name", ["all_equal", "collinear", "two_points"])
def test_degenerate_clouds_give_the_hosts_cubes(name):
    """One location (spacing 1), a line, fewer locations than the spacing's 17 (the host's k lowered alike)."""
    p = degenerate_clouds(40)[name].astype(np.float32)
    host = hgjax.neighbourhoods(p, "hkc")
    eager = hgjax.neighbourhoods(p, "hkc", search="jax")
    _assert_same_cubes(eager, host)
    assert np.isfinite(np.asarray(eager.scale)).all()
    jitted = _jitted_like(eager, p)
    assert int(jitted.overflow) == 0
    _assert_same_cubes(jitted, host)
