"""The tiled engine with its tiles built by the traced search (search="jax", the GPU/TPU default)."""

import jax
import numpy as np
import pytest

import hgjax
from hgjax import engine, tiles
from hgjax.neighbours import backend, nearest, spatial
from fixtures import smooth_and_rounded

pytestmark = pytest.mark.full


@pytest.fixture(scope="module")
def cloud():
    return smooth_and_rounded()["rounded"]  # ties and duplicates


def test_the_traced_index_query_is_the_host_query(cloud):
    x = cloud.astype(np.float64) - 0.37  # a frame whose coordinates float32 cannot hold
    index = spatial.SpatialIndex(x, dedupe=True, gid=np.arange(x.shape[0]) * 3 + 5)
    rows = np.arange(0, index.n, 2)
    for k in (8, 17):
        host, traced = index.knn(k, rows), nearest.index_knn(index, k, rows)
        np.testing.assert_array_equal(traced[0], host[0])
        np.testing.assert_array_equal(traced[1], host[1])
    small = spatial.SpatialIndex(x[:10])  # fewer points than k: padded with n, reach inf
    for got, want in zip(nearest.index_knn(small, 16, np.arange(10)), small.knn(16, np.arange(10))):
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("method", ["ea", "mss"])
def test_traced_tiles_keep_what_host_tiles_keep(cloud, method):
    want = tiles.resample(cloud, 0.2, method=method, tile=0.6, return_scores=True)
    got = tiles.resample(cloud, 0.2, method=method, tile=0.6, search="jax", return_scores=True)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
    np.testing.assert_array_equal(engine.run(cloud, 0.2, method=method, params={"search": "jax"}).idx,
                                  hgjax.resample(cloud, 0.2, method=method))


def test_a_method_whose_tiles_search_on_the_host_refuses_jax_tiles(cloud):
    host_only = next(name for name, entry in hgjax.METHODS.items()
                     if isinstance(entry, hgjax.Method) and "jax" not in entry.tiling.searches)
    with pytest.raises(ValueError, match="builds its tiles with search in"):
        tiles.resample(cloud, 0.2, method=host_only, tile=0.6, search="jax")


def test_the_default_search_follows_the_backend(monkeypatch):
    assert backend.default_search() == ("host" if jax.default_backend() == "cpu" else "jax")
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    assert engine.searched(hgjax.METHODS["ea"], {}) == {"search": "jax"}
    assert engine.searched(hgjax.METHODS["ea"], {"search": "host"}) == {"search": "host"}
    host_only = next(e for e in hgjax.METHODS.values() if isinstance(e, hgjax.Method) and "jax" not in e.tiling.searches)
    assert engine.searched(host_only, {}) == {}
