"""search="jax" for GFR: its graph (both variants) and its top-score resample in pure JAX, equal to the host's."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hgjax
from fixtures import degenerate_clouds, smooth_and_rounded

pytestmark = pytest.mark.full

VARIANTS = ["invariant", "reference"]


@pytest.fixture(scope="module")
def clouds():
    return smooth_and_rounded()


@pytest.fixture(scope="module")
def built(clouds):
    """(host, eager traced) neighbourhoods of every cloud and variant, built once."""
    out = {}
    for which, p in clouds.items():
        for variant in VARIANTS:
            # the first build starts wide enough for the graph's blocks: fewer rounds of growth to compile
            out[which, variant] = (hgjax.neighbourhoods(p, "gfr", variant=variant),
                                   hgjax.neighbourhoods(p, "gfr", variant=variant, search="jax", cell_slots=512))
    return out


@functools.partial(jax.jit, static_argnames=("variant", "capacity", "cell_slots"))
def _jitted(points, cell_edge, *, variant, capacity, cell_slots):
    """The traced build inside jit, one program per static setting (shared by clouds of one N)."""
    return hgjax.neighbourhoods(points, "gfr", variant=variant, search="jax", capacity=capacity,
                                cell_slots=cell_slots, cell_edge=cell_edge)


def _jit_build(points, variant, settings, cell_slots=8):
    return _jitted(points, None, variant=variant, capacity=settings["capacity"], cell_slots=cell_slots)


def _searched(nb) -> dict:
    """The columns an eager build ended with, to pass back inside jit."""
    return {"capacity": nb.idx.shape[-1]}


def _first(nb) -> np.ndarray:
    """``nb.first``, the identity where it is None (every point its own location)."""
    n = nb.points.shape[0]
    return np.arange(n) if nb.first is None else np.asarray(nb.first)


def _assert_same_graph(got, host, *, first_may_be_identity=False):
    np.testing.assert_array_equal(np.asarray(got.idx), host.idx)
    assert got.idx.dtype == host.idx.dtype
    np.testing.assert_array_equal(np.asarray(got.points), np.asarray(host.points))
    assert got.points.dtype == host.points.dtype
    if first_may_be_identity:
        np.testing.assert_array_equal(_first(got), _first(host))
    else:
        assert (got.first is None) == (host.first is None)
        if host.first is not None:
            np.testing.assert_array_equal(np.asarray(got.first), host.first)


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("which", ["smooth", "rounded"])
def test_traced_graph_equals_the_host(built, which, variant):
    host, eager = built[which, variant]
    _assert_same_graph(eager, host)
    params = dict(eager.params)
    assert params["search"] == "jax" and int(eager.overflow) == 0
    assert {k: v for k, v in params.items() if k != "search"} == dict(host.params)
    np.testing.assert_array_equal(np.asarray(hgjax.score(eager, "gfr", variant=variant)),
                                  np.asarray(hgjax.score(host, "gfr", variant=variant)))


@pytest.mark.parametrize("variant", VARIANTS)
def test_jitted_graph_equals_the_eager_one(clouds, built, variant):
    p = clouds["rounded"]
    host, eager = built["rounded", variant]
    jitted = _jit_build(p, variant, _searched(eager))
    assert int(jitted.overflow) == 0
    assert dict(jitted.params) == dict(eager.params)
    _assert_same_graph(jitted, host, first_may_be_identity=True)
    np.testing.assert_array_equal(np.asarray(hgjax.score(jitted, "gfr", variant=variant)),
                                  np.asarray(hgjax.score(host, "gfr", variant=variant)))


def test_jitted_graph_without_duplicates_scores_as_the_host(clouds, built):
    """Under jit ``first`` is always an array (the identity here): the same scores as the host's None."""
    host, eager = built["smooth", "invariant"]
    jitted = _jit_build(clouds["smooth"], "invariant", _searched(eager))
    assert host.first is None and eager.first is None
    np.testing.assert_array_equal(np.asarray(jitted.first), np.arange(host.idx.shape[0]))
    np.testing.assert_array_equal(np.asarray(jitted.idx), host.idx)
    np.testing.assert_array_equal(np.asarray(hgjax.score(jitted, "gfr")), np.asarray(hgjax.score(host, "gfr")))


@pytest.mark.parametrize("variant", VARIANTS)
def test_rows_in_blocks_give_the_same_graph(clouds, built, monkeypatch, variant):
    """The per-row work in blocks of rows (the last one padded) as in one block."""
    monkeypatch.setattr(hgjax.neighbours.traced_graph, "ROW_BLOCK", 500)
    host, eager = built["smooth", variant]
    settings = _searched(eager)
    jitted = jax.jit(lambda q: hgjax.neighbourhoods(q, "gfr", variant=variant, search="jax", **settings))
    _assert_same_graph(jitted(clouds["smooth"]), host, first_may_be_identity=True)


def test_vmap_over_a_batch_equals_the_host(clouds, built):
    batch = np.stack([clouds["smooth"], clouds["smooth"][::-1] + np.float32(0.25)])
    settings = _searched(built["smooth", "invariant"][1])
    nbs = jax.vmap(lambda q: hgjax.neighbourhoods(q, "gfr", search="jax", **settings))(batch)
    assert not np.asarray(nbs.overflow).any()
    for b in range(2):
        host = hgjax.neighbourhoods(batch[b], "gfr", capacity=settings["capacity"])
        np.testing.assert_array_equal(np.asarray(nbs.idx[b]), host.idx)


def test_traced_graph_equals_the_host_in_float64(clouds):
    with jax.enable_x64(True):
        p = clouds["rounded"].astype(np.float64)
        host = hgjax.neighbourhoods(p, "gfr")
        eager = hgjax.neighbourhoods(p, "gfr", search="jax", cell_slots=512)
        _assert_same_graph(eager, host)
        assert eager.points.dtype == jnp.float64


def test_jitted_top_resample_equals_the_host(clouds, built):
    p = clouds["rounded"]
    settings = _searched(built["rounded", "invariant"][1])
    host = hgjax.resample(p, 0.2, method="gfr", mode="top")
    got = jax.jit(lambda q: hgjax.resample(q, 0.2, method="gfr", mode="top", search="jax", **settings))(p)
    np.testing.assert_array_equal(np.asarray(got), host)
    eager = hgjax.resample(p, 0.2, method="gfr", mode="top", search="jax", cell_slots=512)
    np.testing.assert_array_equal(np.asarray(eager), host)


def test_the_random_selection_is_refused_by_the_traced_resample(clouds):
    with pytest.raises(ValueError, match="selects on the host.*mode=.top."):
        jax.jit(lambda q: hgjax.resample(q, 0.2, method="gfr", key=jax.random.key(0)))(clouds["smooth"])


def test_a_row_wider_than_its_columns_under_jit_stops_the_program(clouds, built):
    p = clouds["smooth"]
    for variant in VARIANTS:
        settings = {**_searched(built["smooth", variant][1]), "capacity": 8}
        with pytest.raises(jax.errors.JaxRuntimeError, match=r"capacity=\d+"):
            _jit_build(p, variant, settings).idx.block_until_ready()
    with pytest.raises(ValueError, match="capacity=8 is too small"):  # eagerly, as the host
        hgjax.neighbourhoods(p, "gfr", search="jax", **settings)


def test_few_slots_read_every_candidate(clouds, built):
    p = clouds["rounded"]
    few = hgjax.neighbourhoods(p, "gfr", variant="reference", search="jax", cell_slots=8)
    assert int(few.overflow) == 0
    _assert_same_graph(few, built["rounded", "reference"][0])


@pytest.mark.parametrize("name", ["all_equal", "duplicates", "collinear"])
@pytest.mark.parametrize("variant", VARIANTS)
def test_degenerate_clouds(name, variant):
    p = degenerate_clouds()[name].astype(np.float32)
    x64 = name == "collinear" and variant == "invariant"
    # float32 pairs cannot follow float64's rounding where a pair's length equals the radius exactly (here: ten
    # equal steps on the line); x64 computes the host's float64 bits
    with jax.enable_x64(x64):
        host = hgjax.neighbourhoods(p, "gfr", variant=variant)
        eager = hgjax.neighbourhoods(p, "gfr", variant=variant, search="jax")
        _assert_same_graph(eager, host)
        np.testing.assert_array_equal(np.asarray(hgjax.score(eager, "gfr", variant=variant)),
                                      np.asarray(hgjax.score(host, "gfr", variant=variant)))
