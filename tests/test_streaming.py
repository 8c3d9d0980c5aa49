"""Streaming: a few chunk shapes compile for every cloud and tile size, chunk size never changes results."""

import jax
import numpy as np
import pytest

import hgjax
from fixtures import backend_compiles, box_surface
from hgjax import _stream
from hgjax.scores import ea, hkc, hkf, lhf

SCORING = sorted(m for m, entry in hgjax.METHODS.items() if isinstance(entry, hgjax.Method))
# (method, params) pairs covering every streamed kernel and variant
VARIANTS = [("hkc", {}), ("hkc", {"variant": "reference"}), ("hkf", {}), ("hkf", {"variant": "reference"}),
            ("lhf", {}), ("lhf", {"variant": "reference"}), ("lhf", {"solver": "eigh"}), ("ea", {}), ("pca_ac", {})]


@pytest.mark.full
@pytest.mark.parametrize("method", SCORING)
def test_every_scoring_method_is_chunk_invariant_through_resample(method):
    p = box_surface(3000, seed=1)
    key = jax.random.key(0)
    base = hgjax.resample(p, 0.2, method=method, key=key)
    for chunk in (256, 2500):  # 3 chunks of one block, 1 padded chunk of 3 blocks
        np.testing.assert_array_equal(hgjax.resample(p, 0.2, method=method, key=key, chunk_size=chunk), base)


@pytest.mark.full
@pytest.mark.parametrize("method, params", VARIANTS, ids=[f"{m}-{'-'.join(map(str, p.values()))}" for m, p in VARIANTS])
def test_scores_are_bitwise_chunk_invariant(method, params):
    p = box_surface(3000, seed=2)
    nb = hgjax.neighbourhoods(p, method, **params)
    base = np.asarray(hgjax.score(nb, method, **params))
    for chunk in (1, 1024, 1025, 10_000):
        np.testing.assert_array_equal(np.asarray(hgjax.score(nb, method, chunk_size=chunk, **params)), base)
    # the traced path (inside a caller's jit) computes every row with the same block
    traced = jax.jit(lambda nb: hgjax.score(nb, method, **params))(nb)
    np.testing.assert_array_equal(np.asarray(traced), base)


def test_chunk_rows_come_from_a_fixed_set_and_fit_small_streams():
    unit = _stream.BLOCK * len(jax.devices())
    assert _stream.chunk_rows() == _stream.CHUNK_BLOCKS * unit
    assert _stream.chunk_rows(1) == unit and _stream.chunk_rows(unit + 1) == 2 * unit
    for total, blocks in ((1, 1), (unit, 1), (unit + 1, 2), (3 * unit, 4), (10**7, _stream.CHUNK_BLOCKS)):
        assert _stream.chunk_rows(total=total) == blocks * unit, total
    assert _stream.chunk_rows(3 * unit, total=10 * unit) == 3 * unit  # a requested size is the largest chunk
    assert _stream.chunk_rows(3 * unit, total=unit + 1) == 2 * unit
    assert len({_stream.chunk_rows(total=t) for t in range(1, 20 * unit, 97)}) == _stream.CHUNK_BLOCKS.bit_length()


@pytest.mark.full
def test_large_float32_streaming_run_with_small_chunks():
    p = box_surface(100_000, seed=2).astype(np.float32)
    nb = hgjax.neighbourhoods(p, "lhf")
    assert nb.points.dtype == np.float32
    small = np.asarray(hgjax.score(nb, "lhf", chunk_size=4096))  # 25 chunks, the last one padded
    np.testing.assert_array_equal(small, np.asarray(hgjax.score(nb, "lhf")))
    assert small.dtype == np.float32 and np.isfinite(small).all()
    idx = hgjax.keep(small, 0.2, method="lhf")
    assert len(np.unique(idx)) == 20_000


@pytest.mark.full
def test_compilations_are_bounded_by_the_chunk_sizes_whatever_the_cloud_size():
    sizes = [_stream.BLOCK << i for i in range(_stream.CHUNK_BLOCKS.bit_length())]  # 1, 2, 4, ... blocks
    kernels = [(hkc._kernel(3, "invariant"), 1, "hkc", True), (hkf._kernel(3, "invariant"), 1, "hkf", True),
               (lhf._kernel(lhf.DEFAULT_LENGTHS, "invariant", "gram"), 0, "lhf", False),
               (ea.variation, 0, "ea", False)]
    for fn, n_row_args, method, narrow in kernels:
        kernel = _stream._jitted(fn, n_row_args)
        before = kernel._cache_size()
        # a fixed capacity: the same K for every cloud (the HKC/HKF cube never holds 256 points)
        clouds = [hgjax.neighbourhoods(box_surface(n, seed=seed), method, capacity=256)
                  for n, seed in ((5000, 3), (700, 4), (3000, 5), (20_000, 6))]
        for nb in clouds:
            for chunk in sizes + [None]:
                hgjax.score(nb, method, chunk_size=chunk)
        widths = {cut.shape[1] for nb in clouds
                  for _, cut in (_stream.narrow_split(nb.idx, len(nb.points)) if narrow else [(0, nb.idx)])}
        assert kernel._cache_size() - before <= len(sizes) * len(widths), method
        if narrow:
            continue
        compiled = kernel._cache_size()
        with backend_compiles() as events:  # other data, other sizes, more chunks: the shapes are compiled
            for n, seed in ((4000, 7), (12_000, 8), (300, 9)):
                nb = hgjax.neighbourhoods(box_surface(n, seed=seed), method, capacity=256)
                hgjax.score(nb, method, chunk_size=4096)
                hgjax.score(nb, method)
        assert kernel._cache_size() == compiled, method
        assert events == [], (method, events)


@pytest.mark.full
@pytest.mark.parametrize("method", ["hkc", "lhf", "ea", "mss", "gfr"])
def test_eager_soft_scores_of_a_new_cloud_size_compile_nothing(method):
    """Called eagerly, a soft score streams through its compiled kernel as hgjax.score does: once it
    has run on a cloud, another cloud of another size in the same chunk (two blocks) and a new tau
    compile nothing; GFR's runs as one program per size. The values are the jitted soft score's."""
    capacity = 256 if method == "hkc" else None  # one K for every cloud (the cube never holds 256 points)
    params = {"tau": 0.2} if method in ("hkc", "lhf") else {}
    hgjax.soft_score(hgjax.neighbourhoods(box_surface(2000, seed=10), method, capacity=capacity), method)
    with backend_compiles() as events:
        for n, seed in ((1500, 11), (1900, 12)):
            nb = hgjax.neighbourhoods(box_surface(n, seed=seed), method, capacity=capacity)
            eager = hgjax.soft_score(nb, method, **params)
    if method == "gfr":  # one program over the whole cloud: one compilation of it per size
        assert events.count("jit(_soft)") == 2, events
    else:
        assert events == [], (method, events)
    jitted = jax.jit(lambda nb: hgjax.soft_score(nb, method, **params))(nb)
    np.testing.assert_allclose(eager, jitted, rtol=1e-12)


def test_float_parameter_sweeps_do_not_recompile():
    nb = hgjax.neighbourhoods(box_surface(2000, seed=7), "lhf")
    weights = jax.jit(lambda nb, ratio, temperature, tau: hgjax.soft_weights(
        nb, ratio, method="lhf", temperature=temperature, tau=tau))
    weights(nb, 0.1, 0.05, 0.1)
    with backend_compiles() as events:
        for ratio in (0.2, 0.3, 0.5):
            weights(nb, ratio, ratio / 4, ratio / 2)
    assert events == []
    assert weights._cache_size() == 1
    # HKC's d_factor changes the neighbourhoods (host), never the kernel of a row width: a
    # sweep compiles only the narrow widths (_stream.narrow_widths) its counts newly select
    kernel = _stream._jitted(hkc._kernel(3, "invariant"), 1)
    p = box_surface(2000, seed=8)

    def widths(nb):
        return set(_stream.narrow_widths((np.asarray(nb.idx) < len(p)).sum(axis=1)).tolist())

    nb = hgjax.neighbourhoods(p, "hkc", capacity=256)
    hgjax.score(nb, "hkc")
    seen, new, compiled = widths(nb), set(), kernel._cache_size()
    with backend_compiles() as events:
        for d_factor in (1.6, 2.0, 1.6, 2.0):
            nb = hgjax.neighbourhoods(p, "hkc", d_factor=d_factor, capacity=256)
            new |= widths(nb) - seen
            hgjax.score(nb, "hkc")
    assert kernel._cache_size() - compiled <= len(new) and len(events) <= len(new)


@pytest.mark.parametrize("method", ["hkc", "hkf"])
def test_narrow_stream_gives_each_row_the_wide_kernels_score_in_push_order(method):
    # rows pushed in uneven parts go to kernels of different widths and come back in push order
    nb = hgjax.neighbourhoods(box_surface(3000, seed=9), method, capacity=256)
    points, idx, scale = np.asarray(nb.points), np.asarray(nb.idx), np.asarray(nb.scale)
    fn = (hkc if method == "hkc" else hkf)._kernel(3, "invariant")
    ext = _stream.device_points(points, points.dtype)
    wide = _stream.Stream(fn, ext, chunk_size=1024)
    wide.push(np.arange(len(points)), idx, (scale,))
    narrow = _stream.NarrowStream(fn, ext, chunk_size=1024)
    order = np.random.default_rng(0).permutation(len(points))
    for part in np.array_split(order, [5, 1200, 1201]):
        narrow.push(part, idx[part], (scale[part],))
    assert len(narrow.streams) >= 2
    assert set(narrow.streams) <= set(_stream.narrow_widths((idx < len(points)).sum(axis=1)).tolist())
    np.testing.assert_array_equal(narrow.collect(), wide.collect()[order])


def test_half_step_widths_hold_every_row_in_a_few_widths():
    count = np.arange(300)
    width = _stream.narrow_widths(count, half_steps=True)
    assert (width >= np.maximum(count, 1)).all() and (width <= _stream.narrow_widths(count)).all()
    assert set(width.tolist()) == {8, 12, 16, 24, 32, 48, 64, 96, 128, 192, 256, 384}
