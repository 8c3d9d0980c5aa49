"""The tiled engine with its tiles built by the traced search (search="jax", the GPU/TPU default)."""

import jax
import numpy as np
import pytest

import hgjax
from hgjax import engine, tiles
from hgjax.neighbours import backend, balls, nearest, radius_graph, spatial
from fixtures import smooth_and_rounded

pytestmark = pytest.mark.full

TILED = [("ea", {}), ("mss", {}), ("hkc", {}), ("hkf", {}), ("hkc", {"variant": "reference"}), ("gfr", {"mode": "top"})]


@pytest.fixture(scope="module")
def cloud():
    return smooth_and_rounded()["rounded"]  # ties and duplicates


@pytest.fixture(scope="module")
def index(cloud):
    """A tile's index: coordinates float32 cannot hold, global ids that are not the rows."""
    x = cloud.astype(np.float64) - 0.37
    return lambda dedupe: spatial.SpatialIndex(x, dedupe=dedupe, gid=np.arange(x.shape[0]) * 3 + 5)


def test_the_traced_index_query_is_the_host_query(index):
    deduped = index(True)
    rows = np.arange(0, deduped.n, 2)
    for k in (8, 17):
        host, traced = deduped.neighbours(k, rows), nearest.index_knn(deduped, k, rows)
        np.testing.assert_array_equal(traced[0], host[0])
        np.testing.assert_array_equal(traced[1], host[1])
    small = spatial.SpatialIndex(deduped.points[:10])  # fewer points than k: padded with n, reach inf
    for got, want in zip(nearest.index_knn(small, 16, np.arange(10)), small.neighbours(16, np.arange(10))):
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("params", [{"variant": "invariant"}, {"variant": "reference"},
                                    {"variant": "invariant", "resolution": 0.2}])
def test_the_traced_index_cubes_are_the_host_batches(index, params):
    build = balls.build_params(**params)
    tile = index(build["dedupe"])
    build = balls.resolve(build, spatial.sample_stats(tile))
    rows = np.arange(1, tile.n, 3)
    (part, *host), = balls.row_batches(tile, rows, build)  # one batch: every row
    assert part == slice(0, rows.size)
    traced = balls.index_balls(tile, rows, build)
    for got, want in zip(traced, host):
        np.testing.assert_array_equal(got, want)
    assert (host[0] < tile.n).sum(axis=1).max() > 8  # balls, not single points


def test_the_traced_index_graph_is_the_host_graph(index):
    tile = index(True)
    r = radius_graph.squared_radius(radius_graph.RADIUS_FACTOR, spatial.sample_stats(tile))
    want = np.zeros(tile.n, bool)
    want[::3] = True

    def partners(chunks):
        return {int(a): sorted(row[row < tile.n].tolist()) for own, sym in chunks for a, row in zip(own, sym)}

    for max_nn in (12, radius_graph.MAX_NN):  # capped rows, whose pairs are also the rows that keep them
        host = partners(radius_graph.location_rows(tile, r, max_nn, want))
        assert partners(radius_graph.index_location_rows(tile, r, max_nn, want)) == host
        assert sorted(host) == np.flatnonzero(want).tolist() and max(map(len, host.values())) > max_nn


@pytest.mark.parametrize("dtype", ["float32", "float64"])
@pytest.mark.parametrize("method, params", TILED, ids=[m + "-" + "-".join(p.values()) for m, p in TILED])
def test_traced_tiles_keep_what_one_tile_and_the_host_keep(cloud, method, params, dtype):
    """A core point's traced neighbourhood and score are the same in every tile that holds it: every tiling
    keeps the one-tile run's points and scores, bit for bit, and those are the host search's."""
    p = cloud.astype(dtype)
    whole = tiles.resample(p, 0.2, method=method, search="jax", return_scores=True, **params)
    host = tiles.resample(p, 0.2, method=method, search="host", return_scores=True, **params)
    for tile in (None, 2.5, 1.5):
        got = whole if tile is None else tiles.resample(p, 0.2, method=method, tile=tile, search="jax",
                                                        return_scores=True, **params)
        np.testing.assert_array_equal(got[0], host[0])
        np.testing.assert_array_equal(got[1], host[1])


def test_the_default_search_follows_the_backend(monkeypatch):
    assert backend.default_search() == ("host" if jax.default_backend() == "cpu" else "jax")
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    for name, entry in hgjax.METHODS.items():
        if isinstance(entry, hgjax.Method):
            assert engine.searched(entry, {}) == {"search": "jax"}, name
            assert engine.searched(entry, {"search": "host"}) == {"search": "host"}, name
