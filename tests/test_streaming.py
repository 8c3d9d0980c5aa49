"""Streaming: one compilation for all chunks, chunk size never changes results."""

import importlib

import numpy as np
import pytest

import hgjax


hkc_module = importlib.import_module("hgjax.scores.hkc")  # the module, not the function
lhf_module = importlib.import_module("hgjax.scores.lhf")


def box_cloud(n, seed=0):
    return hgjax.eval.box_surface(n, seed=seed)


@pytest.mark.parametrize("method", sorted(set(hgjax.METHODS) - {"uniform", "voxel", "fps"}))
def test_every_chunked_method_is_chunk_invariant(method):
    import jax

    p = box_cloud(3000, seed=1)
    key = jax.random.key(0)
    base = hgjax.resample(p, 0.2, method=method, key=key)
    np.testing.assert_array_equal(hgjax.resample(p, 0.2, method=method, key=key, chunk_size=256), base)


def test_large_streaming_run_with_small_chunks():
    p = box_cloud(100_000, seed=2).astype(np.float32)
    small = hgjax.scores.lhf(p, ratio=0.2, chunk_size=4096)  # 25 chunks, last one padded
    np.testing.assert_array_equal(small, hgjax.scores.lhf(p, ratio=0.2))
    assert small.dtype == np.float32 and np.isfinite(small).all()


def test_compiled_once_for_all_chunks_and_parameter_sweeps():
    kernel = hkc_module._chunk_kernel(3)
    p = box_cloud(5000, seed=3)
    hgjax.scores.hkc(p, chunk_size=1024)
    before = kernel._cache_size()
    hgjax.scores.hkc(box_cloud(5000, seed=4), chunk_size=1024)  # same shapes, other data
    hgjax.scores.hkc(p, chunk_size=1024, d_factor=1.6)  # float parameters are traced
    assert kernel._cache_size() == before
    lk = lhf_module._chunk_kernel(lhf_module.DEFAULT_LENGTHS, "invariant", "gram")
    hgjax.scores.lhf(p, ratio=0.2, chunk_size=1024)
    n_lhf = lk._cache_size()
    hgjax.scores.lhf(p, ratio=0.3, chunk_size=1024)
    assert lk._cache_size() == n_lhf


def test_gfr_scores_are_bitwise_chunk_invariant():
    p = box_cloud(4000, seed=5)
    radius = 2.5 * hgjax.intrinsic_resolution(p)  # a well-connected graph with capped rows
    base = hgjax.scores.gfr(p, radius=radius, max_nn=12)
    assert (base > 0).mean() > 0.9
    for chunk in (256, 1000):
        np.testing.assert_array_equal(hgjax.scores.gfr(p, radius=radius, max_nn=12, chunk_size=chunk), base)
