"""Ragged batches: hgjax.stack_neighbourhoods pads clouds of any N and K into one vmappable batch.

Row b of a batched score equals cloud b's own on its first N_b rows, and its padding rows
score 0, for every score, soft score and soft weights in float32 and float64: the ragged
variant of the variants matrix (tests/fixtures.py, run by tests/test_api.py). Here: the
batch's layout, LHF's order statistics over the real rows only, and soft weights that carry
ratio x N_b of mass per cloud, weigh exactly 0 on padding rows, and give a loss through them
finite gradients that are exactly 0 on padding rows. The clouds differ in shape, N (320 with
exact duplicates, 450, 640) and K (one cloud widened by sentinel columns).
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fixtures
import hgjax

SCORING = sorted(m for m, e in hgjax.METHODS.items() if isinstance(e, hgjax.Method))
RATIO = 0.2


@functools.lru_cache(maxsize=None)
def clouds() -> tuple[np.ndarray, ...]:
    """Three float64 clouds of different shapes and sizes; the first holds 20 exact duplicates."""
    rng = np.random.default_rng(0)
    box = hgjax.eval.box_surface(300, 1)
    union = hgjax.eval.box_union_cloud(seed=2, n_points=450).points
    flat = hgjax.eval.box_surface(640, 3, size=(3.0, 2.0, 0.2))
    return (np.concatenate([box, box[:20]]), union + 0.003 * rng.standard_normal(union.shape),
            flat + 0.002 * rng.standard_normal(flat.shape))


@functools.lru_cache(maxsize=None)
def ragged(method: str, dtype: np.dtype):
    """(per-cloud neighbourhoods, their stacked batch) of :func:`clouds` for a method.

    Cloud 1 enters the batch widened by ``fixtures.WIDEN`` sentinel columns; the per-cloud
    neighbourhoods returned (the references) are the builder's own.
    """
    nbs = [hgjax.neighbourhoods(p.astype(dtype), method) for p in clouds()]
    return nbs, hgjax.stack_neighbourhoods([nbs[0], fixtures.widen(nbs[1], fixtures.WIDEN), nbs[2]])


def soft(method):
    """(soft scores, soft weights) of one cloud, in one program."""
    return lambda nb: (hgjax.soft_score(nb, method), hgjax.soft_weights(nb, RATIO, method=method))


@functools.lru_cache(maxsize=None)
def batched_score(method):
    """jit(vmap) of a method's score over a stacked batch."""
    return jax.jit(jax.vmap(lambda nb: hgjax.score(nb, method)))


# ----------------------------------------------------------------- the batch


def test_stack_pads_rows_and_columns_with_the_sentinel_and_records_counts():
    nbs, batch = ragged("hkc", np.dtype(np.float64))
    n = [nb.points.shape[0] for nb in nbs]
    n_max, k_max = max(n), max(nb.idx.shape[1] + fixtures.WIDEN * (b == 1) for b, nb in enumerate(nbs))
    assert batch.points.shape == (3, n_max, 3) and batch.idx.shape == (3, n_max, k_max)
    assert batch.idx.dtype == np.int32 and batch.count.dtype == np.int32 and batch.count.tolist() == n
    assert batch.method == "hkc" and batch.params == nbs[0].params and batch.first is None
    for b, nb in enumerate(nbs):
        k = nb.idx.shape[1]
        real = batch.idx[b, :n[b], :k]
        np.testing.assert_array_equal(real, np.where(nb.idx < n[b], nb.idx, n_max))  # sentinel remapped only
        assert (batch.idx[b, :, k:] == n_max).all() and (batch.idx[b, n[b]:] == n_max).all()
        assert (batch.idx[b] < n[b]).sum() == (nb.idx < n[b]).sum()  # no padding row is anyone's neighbour
        np.testing.assert_array_equal(batch.points[b, :n[b]], nb.points)
        np.testing.assert_array_equal(batch.points[b, n[b]:], np.broadcast_to(nb.points[0], (n_max - n[b], 3)))
        np.testing.assert_array_equal(batch.scale[b, :n[b]], nb.scale)
        assert (batch.scale[b, n[b]:] == nb.scale[0]).all()
        np.testing.assert_array_equal(batch.row_mask[b], np.arange(n_max) < n[b])
    np.testing.assert_array_equal(np.asarray(batch.row_mask), np.arange(n_max)[None, :] < batch.count[:, None])


def test_stack_fills_first_of_gfr_clouds_without_duplicates():
    nbs, batch = ragged("gfr", np.dtype(np.float64))
    assert nbs[0].first is not None and nbs[1].first is None  # cloud 0 holds exact duplicates
    np.testing.assert_array_equal(batch.first[0, :320], nbs[0].first)
    np.testing.assert_array_equal(batch.first[1], np.arange(batch.points.shape[1]))


def test_a_cloud_cut_from_a_batch_stacks_back_and_scores_eagerly_as_its_own():
    nbs, batch = ragged("lhf", np.dtype(np.float64))
    one = jax.tree.map(lambda x: x[0], batch)
    again = hgjax.stack_neighbourhoods([one, nbs[2]])
    assert again.points.shape == (2, 640, 3) and again.count.tolist() == [320, 640]
    np.testing.assert_array_equal(again.idx[0, :320, :16], nbs[0].idx)
    assert (again.idx[0, :, 16:] == 640).all() and (again.idx[0, 320:] == 640).all()
    one = dataclasses.replace(one, idx=one.idx[:, :16])  # drop the batch's sentinel columns
    eager = np.asarray(hgjax.score(one, "lhf", chunk_size=1024))  # host stream
    np.testing.assert_allclose(eager[:320], np.asarray(hgjax.score(nbs[0], "lhf", chunk_size=1024)), rtol=1e-12)
    assert (eager[320:] == 0).all()


# ----------------------------------------------------------------- soft scores: batch == per cloud


@functools.lru_cache(maxsize=None)
def soft_and_grad(method):
    """(loss, (soft scores, soft weights)) of the batch and the gradient with respect to its points
    of the loss sum_b sum_i w_bi ||p_bi||^2, in one program."""
    def loss(points, batch):
        scores, w = jax.vmap(soft(method))(dataclasses.replace(batch, points=points))
        return jnp.sum(w * jnp.sum(points * points, axis=-1)), (scores, w)

    return jax.jit(jax.value_and_grad(loss, has_aux=True))


@pytest.mark.full
@pytest.mark.parametrize("method", ["lhf", "ea"])
def test_soft_scores_and_weights_of_the_batch_equal_each_clouds_own(method):
    nbs, batch = ragged(method, np.dtype(np.float64))
    (_, (scores, weights)), _ = soft_and_grad(method)(jnp.asarray(batch.points), batch)
    n = nbs[0].points.shape[0]  # cloud 0: the most padding rows
    own_scores, own_weights = jax.jit(soft(method))(nbs[0])
    np.testing.assert_allclose(scores[0, :n], own_scores, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(weights[0, :n], own_weights, rtol=1e-9, atol=1e-12)
    assert (np.asarray(scores[0, n:]) == 0).all() and (np.asarray(weights[0, n:]) == 0).all()


def test_lhf_order_statistics_come_from_the_real_rows_only():
    """Eqs. (15)-(16) over the first N_b rows whatever the padding rows hold (here 1, above every real
    gamma); over all N_max rows (no count) eps moves: the test can fail."""
    nbs, batch = ragged("lhf", np.dtype(np.float64))
    n_max = batch.points.shape[1]
    single = [np.asarray(hgjax.score(nb, "lhf")) for nb in nbs]
    gammas = jnp.asarray(np.stack([np.pad(g, ((0, n_max - g.shape[0]), (0, 0)), constant_values=1.0) for g in single]))
    kept = jax.vmap(lambda c: hgjax._validate.n_keep_any(c, RATIO))(batch.count)  # each cloud's own count
    combine = jax.vmap(lambda g, m, c: hgjax.scores.lhf.combine(g, m, count=c))
    with_count = np.asarray(combine(gammas, kept, jnp.asarray(batch.count)))
    without = np.asarray(jax.vmap(lambda g, m: hgjax.scores.lhf.combine(g, m))(gammas, kept))
    for b, (g, nb) in enumerate(zip(single, nbs)):
        n = nb.points.shape[0]
        assert int(kept[b]) == hgjax._validate.n_keep(n, RATIO)
        np.testing.assert_allclose(with_count[b, :n], hgjax.scores.lhf.combine(g, int(kept[b])), rtol=1e-12)
    assert np.abs(without[0, :320] - with_count[0, :320]).max() > 1e-6


# ----------------------------------------------------------------- soft weights: mass, padding, gradients


# HKF's and PCA-AC's soft weights are HKC's and EA's (the registry's soft scores).
@pytest.mark.full
@pytest.mark.parametrize("method", [m for m in SCORING if m not in ("hkf", "pca_ac")])
def test_soft_weights_hold_ratio_times_each_count_with_zero_gradient_on_padding(method):
    _, batch = ragged(method, np.dtype(np.float64))
    (_, (_, w)), g = soft_and_grad(method)(jnp.asarray(batch.points), batch)
    w, g, rows = np.asarray(w), np.asarray(g), np.asarray(batch.row_mask)
    assert np.isfinite(w).all() and np.isfinite(g).all()
    np.testing.assert_allclose(w.sum(axis=1), RATIO * batch.count, rtol=1e-9)
    assert (w[~rows] == 0).all() and (g[~rows] == 0).all()
    assert np.abs(g[rows]).max() > 0


def test_float32_soft_weights_hold_ratio_times_each_count():
    _, batch = ragged("hkc", np.dtype(np.float32))
    w = np.asarray(jax.jit(jax.vmap(lambda nb: hgjax.soft_weights(nb, RATIO, method="hkc")))(batch))
    assert w.dtype == np.float32 and np.isfinite(w).all() and (w[~np.asarray(batch.row_mask)] == 0).all()
    np.testing.assert_allclose(w.sum(axis=1), RATIO * batch.count, rtol=1e-5)


def test_soft_select_valid_rows_carry_the_whole_mass_and_gradient():
    s = jnp.asarray(np.random.default_rng(4).standard_normal(40))
    valid = jnp.arange(40) < 25
    f = jax.jit(lambda s, valid: hgjax.soft_select(s, 0.4, temperature=0.3, valid=valid))
    w = f(s, valid)
    np.testing.assert_allclose(float(w.sum()), 0.4 * 25, rtol=1e-9)
    np.testing.assert_allclose(w[:25], hgjax.soft_select(s[:25], 0.4, temperature=0.3), rtol=1e-12)
    assert (np.asarray(w[25:]) == 0).all()
    g = jax.jit(jax.grad(lambda s: jnp.sum(f(s, valid) * s)))(s)
    assert (np.asarray(g[25:]) == 0).all() and np.isfinite(g).all() and np.abs(g[:25]).max() > 0
    with pytest.raises(ValueError, match=r"valid must be None or a bool array.*\(40,\).*int"):
        hgjax.soft_select(s, 0.4, valid=jnp.ones(40, jnp.int32))


# ----------------------------------------------------------------- jit(vmap) == vmap


def test_jit_of_vmap_equals_vmap():
    method = "gfr"  # sums over the whole cloud
    _, batch = ragged(method, np.dtype(np.float64))
    plain = jax.vmap(lambda nb: hgjax.score(nb, method))(batch)
    np.testing.assert_allclose(batched_score(method)(batch), plain, rtol=1e-12, atol=1e-15)


# ----------------------------------------------------------------- errors


def test_stack_rejects_bad_lists():
    nbs, _ = ragged("ea", np.dtype(np.float64))
    lhf = hgjax.neighbourhoods(clouds()[1], "lhf")
    with pytest.raises(ValueError, match="at least one"):
        hgjax.stack_neighbourhoods([])
    with pytest.raises(TypeError, match="nbs must be a list of hgjax.Neighbourhoods; got Neighbourhoods"):
        hgjax.stack_neighbourhoods(nbs[0])
    with pytest.raises(TypeError, match=r"nbs\[1\] must be hgjax.Neighbourhoods; got ndarray"):
        hgjax.stack_neighbourhoods([nbs[0], nbs[0].points])
    with pytest.raises(ValueError, match=r"nbs\[1\].method is 'lhf' but nbs\[0\].method is 'ea'"):
        hgjax.stack_neighbourhoods([nbs[0], lhf])
    other = hgjax.neighbourhoods(clouds()[1], "ea", k=8)
    with pytest.raises(ValueError, match=r"nbs\[2\].params is .*'k', 8.* but nbs\[0\].params is .*'k', 16"):
        hgjax.stack_neighbourhoods([nbs[0], nbs[1], other])
    f32 = hgjax.neighbourhoods(clouds()[1].astype(np.float32), "ea")
    with pytest.raises(TypeError, match=r"nbs\[1\].points has dtype float32 but nbs\[0\].points float64"):
        hgjax.stack_neighbourhoods([nbs[0], f32])
    with pytest.raises(ValueError, match=r"nbs\[0\] must be one cloud.*\(2, 640, 3\)"):
        hgjax.stack_neighbourhoods([hgjax.stack_neighbourhoods([nbs[2], nbs[2]])])
    with pytest.raises(ValueError, match=r"nbs\[0\] must hold 1 to 2\^24 - 1 points to be stacked; got 0"):
        hgjax.stack_neighbourhoods([hgjax.Neighbourhoods(np.zeros((0, 3)), np.zeros((0, 4), np.int32))])
    cube = hgjax.cube(clouds()[0], 0.1)
    with pytest.raises(ValueError, match=r"nbs\[1\].scale is set but nbs\[0\].scale is None"):
        hgjax.stack_neighbourhoods([cube, dataclasses.replace(cube, scale=np.ones(320))])


def test_lhf_keeps_the_hosts_count_of_a_traced_cloud_size_in_float32():
    """ceil(0.3 x 100) is 30 on the host; float32 without x64 rounds 0.3 x 100 to 30.000002 (31)."""
    counts = np.arange(1, 3000)
    want = np.array([hgjax._validate.n_keep(int(c), 0.3) for c in counts])
    with jax.enable_x64(False):
        got = jax.jit(jax.vmap(lambda c: hgjax._validate.n_keep_traced(c, 0.3)))(counts.astype(np.int32))
        naive = jax.vmap(lambda c: jnp.ceil(0.3 * c))(counts.astype(np.int32))
    np.testing.assert_array_equal(np.asarray(got), want)
    assert (np.asarray(naive) != want).any()
