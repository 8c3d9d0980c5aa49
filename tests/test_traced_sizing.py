"""Sizing the traced balls (HKC/HKF) and graph (GFR): counted directly, each size compiled once, the host's rows.

``hgjax.capacity`` counts the columns with the host search and compiles nothing; an eager traced
build counts its rows before it writes them, so it compiles its traced program once per shape
bucket, and the same program serves the cloud at any scale; the columns are ``idx.shape[-1]``, not
a recorded parameter, so two eager builds of different widths stack; a jitted update at the
allocation gives the host's rows and one that outgrows it raises, naming the capacity.
"""

import jax
import numpy as np
import pytest

import hgjax
from fixtures import backend_compiles, smooth_and_rounded
from hgjax.neighbours import spatial

BUILDS = [("hkc", {}), ("hkc", {"variant": "reference"}), ("gfr", {}), ("gfr", {"variant": "reference"})]
# GFR's reference rule compares squared distances with a length (the authors' r): its ball, hence its
# columns and its program, change with the scale; every other build's shapes do not.
SCALE_FREE = BUILDS[:3]
TRACED_PROGRAMS = {"hkc": ("jit(_balls)",), "gfr": ("jit(_search)", "jit(_pairs_of)", "jit(_rows)")}


def _squeezed(p):
    """``p`` with the half beyond its median x squeezed 4x along x: that half 4x denser."""
    return np.where(p[:, :1] > np.median(p[:, 0]), p * np.float32([0.25, 1, 1]), p)


@pytest.fixture(scope="module")
def cloud():
    return smooth_and_rounded()["smooth"]


@pytest.mark.parametrize(("method", "params"), BUILDS)
def test_capacity_is_the_host_rows_bucket_and_compiles_nothing(cloud, method, params):
    with backend_compiles() as compiles:
        cols = hgjax.capacity(cloud, method, **params)
    assert compiles == []
    host = hgjax.neighbourhoods(cloud, method, **params)
    assert cols >= host.idx.shape[-1] and cols == spatial.bucket(cols)
    if params.get("variant") != "reference" or method != "gfr":
        assert cols == host.idx.shape[-1]


@pytest.mark.full
@pytest.mark.parametrize(("method", "params"), SCALE_FREE)
def test_an_eager_build_compiles_its_program_once_for_clouds_of_any_scale(cloud, method, params):
    """The rows counted before they are written: one compilation per program, none for the same
    cloud 1000x larger (its cell edge and radii are traced values), and the host's rows both times."""
    with backend_compiles() as first:
        nb = hgjax.neighbourhoods(cloud, method, search="jax", **params)
    with backend_compiles() as again:
        scaled = hgjax.neighbourhoods(cloud * np.float32(1000), method, search="jax", **params)
    for name in TRACED_PROGRAMS[method]:
        assert first.count(name) <= 1, first
    assert not set(again) & set(TRACED_PROGRAMS[method]), again
    for got, p in ((nb, cloud), (scaled, cloud * np.float32(1000))):
        host = hgjax.neighbourhoods(p, method, **params)
        np.testing.assert_array_equal(np.asarray(got.idx), host.idx)
    assert "capacity" not in dict(nb.params)


@pytest.mark.full
def test_the_reference_graph_counts_its_ball_before_its_one_search(cloud):
    with backend_compiles() as compiles:
        nb = hgjax.neighbourhoods(cloud, "gfr", variant="reference", search="jax")
    for name in TRACED_PROGRAMS["gfr"]:
        assert compiles.count(name) <= 1, compiles
    np.testing.assert_array_equal(np.asarray(nb.idx), hgjax.neighbourhoods(cloud, "gfr", variant="reference").idx)


@pytest.mark.full
def test_two_eager_traced_builds_of_different_widths_stack(cloud):
    small = _squeezed(hgjax.eval.box_union_cloud(seed=1, n_points=500).points.astype(np.float32))
    nbs = [hgjax.neighbourhoods(p, "hkc", variant="reference", search="jax") for p in (cloud, small)]
    hosts = [hgjax.neighbourhoods(p, "hkc", variant="reference") for p in (cloud, small)]
    assert [nb.idx.shape[-1] for nb in nbs] == [h.idx.shape[-1] for h in hosts] == [16, 32]
    batch = hgjax.stack_neighbourhoods(nbs)
    scores = jax.vmap(lambda b: hgjax.score(b, "hkc"))(batch)
    for b, host in enumerate(hosts):
        n = host.idx.shape[0]
        np.testing.assert_allclose(np.asarray(scores[b, :n]), np.asarray(hgjax.score(host, "hkc")), rtol=1e-5)


@pytest.mark.full
def test_a_jitted_update_at_the_allocation_is_the_host_until_the_cloud_outgrows_it(cloud):
    cols = hgjax.capacity(cloud, "hkc", variant="reference")
    update = jax.jit(lambda p: hgjax.neighbourhoods(p, "hkc", variant="reference", search="jax", capacity=cols))
    moved = [cloud + np.float32(t) * np.sin(7 * cloud) for t in (0.0, 0.01)]
    with backend_compiles() as compiles:
        got = [np.asarray(update(p).idx) for p in moved]
    assert compiles.count("jit(<lambda>)") == 1
    for idx, p in zip(got, moved):
        np.testing.assert_array_equal(idx, hgjax.neighbourhoods(p, "hkc", variant="reference", capacity=cols).idx)
    squeezed = _squeezed(cloud)
    needed = hgjax.capacity(squeezed, "hkc", variant="reference")
    assert needed > cols
    with pytest.raises(jax.errors.JaxRuntimeError, match=r"capacity=\d+"):
        update(squeezed).idx.block_until_ready()
