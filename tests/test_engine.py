"""The engine's routes: a traced resample is one pure-JAX program, an eager one runs on the host's engine with
either neighbour search; every route keeps the same points in the same order."""

import jax
import numpy as np
import pytest

import hgjax
from fixtures import box_union


@pytest.fixture(scope="module")
def cloud():
    return box_union(1500).astype(np.float32)


def test_a_jitted_resample_needs_no_search_named(cloud):
    host = hgjax.resample(cloud, 0.2, method="ea")
    got = jax.jit(lambda p: hgjax.resample(p, 0.2, method="ea"))(cloud)
    assert isinstance(got, jax.Array)
    np.testing.assert_array_equal(np.asarray(got), host)


@pytest.mark.parametrize("method", ["ea", "hkc"])
def test_the_search_picks_the_neighbours_only(cloud, method):
    """search="jax" eagerly runs the host's engine (NumPy out) on the traced search's neighbourhoods; traced=True
    runs the same resample as one JAX program: the host's array either way."""
    host = hgjax.resample(cloud, 0.2, method=method)
    eager = hgjax.resample(cloud, 0.2, method=method, search="jax")
    assert isinstance(eager, np.ndarray)
    np.testing.assert_array_equal(eager, host)
    program = hgjax.resample(cloud, 0.2, method=method, traced=True)
    assert isinstance(program, jax.Array)
    np.testing.assert_array_equal(np.asarray(program), host)


def test_either_search_runs_in_tiles(cloud):
    stages = []
    idx = hgjax.tiles.resample(cloud, 0.2, method="ea", search="jax", tile=2.5,
                               on_stage=lambda name, _: stages.append(name))
    np.testing.assert_array_equal(idx, hgjax.resample(cloud, 0.2, method="ea"))
    assert stages == ["plan", "tiles", "keep"]


def test_a_traced_resample_runs_the_traced_search(cloud):
    with pytest.raises(ValueError, match="traced=True runs the whole resample in JAX.*search='host'"):
        hgjax.resample(cloud, 0.2, method="ea", traced=True, search="host")
    with pytest.raises(TypeError, match="traced must be"):
        hgjax.resample(cloud, 0.2, method="ea", traced="yes")


def test_traced_points_refuse_the_host_engine(cloud):
    with pytest.raises(TypeError, match="points are traced.*traced=True"):
        jax.jit(lambda p: hgjax.resample(p, 0.2, method="ea", traced=False))(cloud)
