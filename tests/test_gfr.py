"""GFR baseline: graph + high_pass against the naive transcription, invariance, JAX transforms."""

from __future__ import annotations

import functools
import math
from collections import Counter
from fractions import Fraction

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

import hgjax
from hgjax import _stream

from conftest import TOL
from fixtures import box_surface, degenerate_clouds, grid, uniform_cloud
from hgjax.neighbours import radius_graph, spatial
from hgjax.scores import gfr as gfr_module
from naive import gfr_naive, gfr_pairs

graph, high_pass = radius_graph.graph, gfr_module.high_pass


def pairs_of(g):
    """Sorted point pairs (i, j), i < j, of graph()'s (idx, first): the stored pairs, each
    location pair expanded to every copy of its two locations."""
    idx, first = g
    t, c = np.nonzero(idx < idx.shape[0])
    stored = zip(t.tolist(), idx[t, c].tolist())
    if first is None:
        return sorted(stored)
    copies = {i: np.flatnonzero(first == i).tolist() for i in np.unique(first).tolist()}
    return sorted({(min(x, y), max(x, y)) for a, b in stored for x in copies[a] for y in copies[b]})


def clouds():
    rng = np.random.default_rng(3)
    base = rng.random((150, 3))
    jittered = grid((6, 6, 6), 0.1, seed=1) + 1e-3 * rng.standard_normal((216, 3))
    return {
        "random": rng.random((300, 3)),
        "random_x7": 7 * rng.random((300, 3)),
        "box_surface": box_surface(400, 0),
        "jittered_grid": jittered,
        "duplicates": np.concatenate([base, base[:40], base[:5]]),
        "capped_grid": grid((8, 8, 8), 0.0625, seed=2),  # minNN == maxNN, the ball holds every point
        # a sheet whose density falls 50-fold along x, as on a scan: balls hold many times max_nn points at
        # the dense end, where rows keep partners beyond their own cut (kept by the sparser end)
        "graded": np.column_stack([rng.random(800) ** 4, rng.random(800), 1e-3 * rng.random(800)]),
    }


def kept(scores, ratio=0.2):
    """The ceil(ratio N) largest scores (ties by index), as GFR's mode="top" keeps them."""
    s = np.asarray(scores)
    return np.argsort(-s, kind="stable")[: math.ceil(ratio * len(s))]


def overlap(a, b):
    return np.intersect1d(a, b).size / len(b)


jitted_high_pass = jax.jit(high_pass, static_argnames="weights_dtype")


def scores(points, variant="invariant", **kw):
    idx, first = graph(points, variant=variant, **kw)
    weights = np.float32 if variant == "reference" else None
    return np.asarray(jitted_high_pass(jnp.asarray(points), jnp.asarray(idx), first=first, weights_dtype=weights))


# ------------------------------------------------------------------ reference vs naive
@pytest.mark.parametrize("name", sorted(clouds()))
def test_reference_graph_is_the_authors_rule(name):
    p = clouds()[name]
    want, _ = gfr_pairs(p)
    idx, first = graph(p, variant="reference")
    assert first is None  # the authors' graph keeps every copy as its own point
    assert idx.dtype == np.int32 and idx.shape[1] == max(Counter(t for t, _ in want).values(), default=1)
    assert pairs_of((idx, first)) == want


@pytest.mark.full
@pytest.mark.parametrize("name", sorted(clouds()))
def test_reference_matches_naive(name, dtype):
    p = clouds()[name].astype(dtype)
    want = gfr_naive(p)
    got = scores(p, "reference")
    assert got.dtype == dtype and (want > 0).mean() > 0.5
    rtol = 1e-6 if dtype == np.float64 else TOL[dtype]
    np.testing.assert_allclose(got, want, rtol=rtol, atol=rtol * want.max())


def test_capped_grid_rows_hit_the_cap():
    p = clouds()["capped_grid"]
    idx, _ = graph(p, variant="reference")
    assert idx.shape[1] == 100 and ((idx < len(p)).sum(axis=1) == 100).sum() > 300
    assert pairs_of(graph(p, variant="reference", max_nn=7)) == gfr_pairs(p, max_nn=7)[0]


def test_reference_ranks_by_float32_squared_distances():
    """The authors' graph judges q in float32: here point 0's two candidates tie in float32 (kept by
    index: point 1), while in float64 point 2 is nearer."""
    p = np.array([[0.7218128442764282, 0.5002991557121277, 0.6625536680221558],
                  [0.7281467914581299, 0.5072412490844727, 0.6690453290939331],
                  [0.7283044457435608, 0.5066331624984741, 0.6694957613945007]], dtype=np.float32)
    q64 = ((p[1:].astype(np.float64) - p[0]) ** 2).sum(axis=1)
    assert q64[1] < q64[0]
    want, _ = gfr_pairs(p, max_nn=1)
    assert want == [(0, 1), (1, 2)]
    assert pairs_of(graph(p, variant="reference", max_nn=1)) == want


def exact_location_graph(index, r, max_nn):
    """(stored, inside) (n, n) bool of a deduplicated index, from all pair distances: each location keeps its
    ``max_nn`` nearest with 0 < q < r by (q, global id), a pair is stored when either end keeps the other."""
    d2 = ((index.points[:, None] - index.points[None]) ** 2).sum(axis=-1)
    inside = (0 < d2) & (d2 < r)
    by_gid = np.argsort(index.gid[:index.n])
    order = np.argsort(np.where(inside, d2, np.inf)[:, by_gid], axis=1, kind="stable")
    keeps = np.zeros_like(inside)
    np.put_along_axis(keeps, by_gid[order[:, :max_nn]], True, axis=1)
    keeps &= inside
    return keeps | keeps.T, inside


@pytest.mark.full
@pytest.mark.parametrize("max_nn", [radius_graph.MAX_NN, 69])
def test_dense_balls_are_asked_once(max_nn):
    """A plane lattice holds about 316 points in a ball of 10 spacings: every row asks one bounded query
    (max_nn + 9 columns), which decides its cut unless a tie with its max_nn-th pair runs past the query,
    and only those rows are asked again, however many points their balls hold (max_nn = 100: none; 69: the
    interior rows, whose 69th to 80th partners lie at distance 5); the rows returned are those of the exact
    radius graph."""
    pts = np.column_stack([grid((60, 60)), np.zeros(3600)])
    index = spatial.SpatialIndex(pts, dedupe=True)
    r = radius_graph.squared_radius(radius_graph.RADIUS_FACTOR, spatial.sample_stats(index))
    asked = []

    class Counted:
        def __init__(self, tree):
            self.tree = tree

        def query(self, x, k, *args, **kw):
            asked.append((k, len(x)))
            return self.tree.query(x, k, *args, **kw)

    index._tree = Counted(index.tree)
    rows = list(radius_graph.location_rows(index, r, max_nn, np.ones(index.n, bool)))
    assert asked[0] == (max_nn + 9, index.n)
    again = sum(n for _, n in asked[1:])
    assert again == 0 if max_nn == radius_graph.MAX_NN else 0.5 * index.n < again < index.n
    got = {(int(a), int(b)) for own, sym in rows for a, row in zip(own, sym) for b in row[row < index.n]}
    stored, inside = exact_location_graph(index, r, max_nn)
    assert inside.sum(axis=1).max() > 300
    assert got == {(int(a), int(b)) for a, b in zip(*np.nonzero(stored))}


@pytest.mark.parametrize("max_nn", [7, 40])
def test_any_rows_in_small_batches_get_their_partners_in_the_whole_graph(monkeypatch, max_nn):
    """The rows of a subset (a scattered one, a corner, none), built in batches of a few rows each, get the
    partners the whole graph gives them: every row of a dense jittered lattice is capped, and the rows that
    keep a wanted row lie in other batches as often as in its own."""
    rng = np.random.default_rng(5)
    pts = np.column_stack([grid((40, 40)) + rng.normal(0, 0.2, (1600, 2)), rng.normal(0, 0.05, 1600)])
    index = spatial.SpatialIndex(pts, dedupe=True)
    r = radius_graph.squared_radius(radius_graph.RADIUS_FACTOR, spatial.sample_stats(index))

    def partners(want):
        return {int(a): sorted(row[row < index.n].tolist()) for own, sym in
                radius_graph.location_rows(index, r, max_nn, want) for a, row in zip(own, sym)}

    stored, inside = exact_location_graph(index, r, max_nn)
    assert (inside.sum(axis=1) > max_nn).all()  # every row capped
    assert (stored.sum(axis=1) > max_nn).mean() > 0.3  # many also kept by rows they do not keep
    monkeypatch.setattr(radius_graph, "PAIR_BUDGET", 40 * (max_nn + 9))  # batches of about 40 rows
    for want in (rng.random(index.n) < 0.3, (index.points[:, :2] < 12).all(axis=1), np.zeros(index.n, bool)):
        got = partners(want)
        assert sorted(got) == np.flatnonzero(want).tolist()
        assert got == {a: np.flatnonzero(stored[a]).tolist() for a in got}


@pytest.mark.parametrize("cloud", [uniform_cloud(500), box_surface(500, 0)],
                         ids=["cube", "box_surface"])
def test_reference_scores_few_exact_zeros(cloud):
    assert (scores(cloud, "reference") == 0).mean() < 0.02


def test_a_float64_context_reaches_the_pair_sums_thread():
    """A process with x64 off that scores inside ``with jax.enable_x64(True)`` (as a Dask worker runs a tile)
    keeps the points of a process with x64 on: the pair sums, taken in a background thread, are float64
    too (a thread starts with the process's setting, not the context's)."""
    p = np.round(hgjax.eval.box_union_cloud(seed=3, n_points=2500).points * 50) / 50  # tied pair lengths
    want = hgjax.resample(p, 0.2, method="gfr", mode="top")
    before = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", False)
    try:
        with jax.enable_x64(True):
            got = hgjax.resample(p, 0.2, method="gfr", mode="top")
    finally:
        jax.config.update("jax_enable_x64", before)
    np.testing.assert_array_equal(got, want)


# ------------------------------------------------------------------ invariant default
@pytest.mark.full
@pytest.mark.parametrize("name", ["random", "box_surface", "duplicates", "jittered_grid", "graded"])
@pytest.mark.parametrize("max_nn", [100, 4])
def test_invariant_matches_naive(name, max_nn):
    p = clouds()[name]
    assert pairs_of(graph(p, max_nn=max_nn)) == gfr_pairs(p, max_nn, radius_graph.RADIUS_FACTOR)[0]
    want = gfr_naive(p, max_nn, radius_graph.RADIUS_FACTOR)
    assert (want > 0).mean() > 0.9
    np.testing.assert_allclose(scores(p, max_nn=max_nn), want, rtol=1e-10, atol=1e-10 * want.max())


def test_resolution_ignores_duplicates_and_outliers():
    p = box_surface(300, 1)  # 3 copies stay within the 1000 sampled points: the median of all of them

    def resolution(q):
        return spatial.sample_stats(spatial.SpatialIndex(q, dedupe=True)).resolution(robust=True)

    res = resolution(p)
    assert resolution(np.concatenate([p, p, p])) == res
    assert abs(resolution(np.concatenate([p, [[1e6, 0, 0]]])) / res - 1) < 0.01
    assert resolution(np.ones((5, 3))) == 0.0


@pytest.mark.parametrize("scale", [1e-3, 1e3])
def test_invariant_kept_set_does_not_change_with_scale(dtype, scale):
    p = box_surface(2000, 2).astype(dtype)
    base = kept(scores(p))
    np.testing.assert_array_equal(kept(scores((p * scale).astype(dtype))), base)


def test_invariant_kept_set_does_not_change_with_translation():
    p = box_surface(2000, 3)
    np.testing.assert_array_equal(kept(scores(p + np.array([5e5, 4e6, 0.0]))), kept(scores(p)))


def test_invariant_keeps_the_same_locations_with_every_point_duplicated():
    p = box_surface(2000, 4)
    locations = np.unique(kept(scores(np.concatenate([p, p]))) % len(p))
    assert overlap(locations, kept(scores(p))) >= 0.95


def test_invariant_keeps_the_same_points_with_a_far_outlier():
    p = box_surface(2000, 5)
    with_outlier = kept(scores(np.concatenate([p, p[:1] + 1e6])))
    assert overlap(with_outlier[with_outlier < len(p)], kept(scores(p))) >= 0.95


def test_invariant_scores_follow_a_permutation():
    p = box_surface(600, 6)
    perm = np.random.default_rng(0).permutation(len(p))
    np.testing.assert_allclose(scores(p[perm]), scores(p)[perm], rtol=1e-12, atol=1e-14)


def test_reference_depends_on_units():
    p = box_surface(600, 7)
    assert overlap(kept(scores(100 * p, "reference")), kept(scores(p, "reference"))) < 0.9


# ------------------------------------------------------------------ JAX transforms
DEGENERATE_WIDTH = 64  # idx padded to one width: one compilation per dtype, variant and first


@functools.partial(jax.jit, static_argnames="weights_dtype")
def scores_and_gradient(points, idx, first, weights_dtype):
    f = lambda x: high_pass(x, idx, first=first, weights_dtype=weights_dtype)  # noqa: E731
    return f(points), jax.grad(lambda x: jnp.sum(f(x)))(points)


@pytest.mark.full
@pytest.mark.parametrize("variant", ["invariant", "reference"])
@pytest.mark.parametrize("name", sorted(degenerate_clouds()))
def test_degenerate_scores_and_gradients_are_finite(name, variant, dtype):
    p = degenerate_clouds()[name].astype(dtype)
    idx, first = graph(p, variant=variant)
    assert idx.shape[1] <= DEGENERATE_WIDTH
    idx = np.pad(idx, ((0, 0), (0, DEGENERATE_WIDTH - idx.shape[1])), constant_values=len(p))
    weights = np.float32 if variant == "reference" else None
    s, g = scores_and_gradient(jnp.asarray(p), idx, first, weights)
    assert s.dtype == dtype and np.isfinite(s).all() and (s >= 0).all() and np.isfinite(g).all()
    if name == "all_equal":
        assert not s.any() and not g.any()


@pytest.mark.full
def test_gradient_finite_when_a_graph_collapses():
    p = box_surface(100, 9)
    idx, _ = graph(p)
    grad = jax.jit(jax.grad(lambda y: jnp.sum(high_pass(y, idx))))
    for x in (np.ones_like(p), 1e-30 * p, np.float32(1e-6) * p.astype(np.float32)):
        g = grad(jnp.asarray(x))
        assert np.isfinite(g).all()


@pytest.mark.full
def test_gradient_matches_finite_differences():
    p = box_surface(60, 10)
    idx, _ = graph(p)
    check_grads(jax.jit(lambda x: high_pass(x, idx)), (jnp.asarray(p),), order=1, modes=["rev"], eps=1e-6, atol=1e-6, rtol=1e-6)


@pytest.mark.full
def test_jit_and_vmap_match_single_calls():
    batch = [box_surface(300, s) for s in range(3)]
    idx = [graph(p)[0] for p in batch]
    k = max(i.shape[1] for i in idx)
    idx = np.stack([np.pad(i, ((0, 0), (0, k - i.shape[1])), constant_values=300) for i in idx])  # (B, N, K)
    single = np.stack([scores(p) for p in batch])
    np.testing.assert_allclose(jax.jit(jax.vmap(high_pass))(jnp.asarray(np.stack(batch)), jnp.asarray(idx)), single,
                               rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(jax.jit(high_pass)(jnp.asarray(batch[0]), jnp.asarray(idx[0])), single[0],
                               rtol=1e-12, atol=1e-14)


def test_float32_matches_float64():
    p = box_surface(500, 11)
    idx, _ = graph(p)
    want = high_pass(jnp.asarray(p), idx)
    got = high_pass(jnp.asarray(p, dtype=jnp.float32), idx)
    assert got.dtype == jnp.float32
    np.testing.assert_allclose(got, want, rtol=TOL[np.dtype(np.float32)], atol=TOL[np.dtype(np.float32)] * want.max())


def _public(p, **params):
    """The public path: hgjax.score on hgjax.neighbourhoods (eager: streamed chunks)."""
    return np.asarray(hgjax.score(hgjax.neighbourhoods(p, "gfr", **params), "gfr", **params))


def test_float64_points_without_x64_are_computed_in_float32():
    p = box_surface(300, 12)
    with jax.enable_x64(False):  # a unit box: float32 loses nothing it holds, no PrecisionWarning
        s = _public(p)
    assert s.dtype == np.float32
    np.testing.assert_allclose(s, _public(p), rtol=1e-3, atol=1e-3 * s.max())


# ------------------------------------------------------------------ host wrapper, arguments
def test_public_path_is_graph_plus_high_pass_and_keeps_inputs():
    p = box_surface(400, 13)
    p.flags.writeable = False
    for variant, rtol in (("invariant", 1e-12), ("reference", 1e-6)):  # jit may round float32 weights otherwise
        want = scores(p, variant)
        np.testing.assert_allclose(_public(p, variant=variant), want, rtol=rtol, atol=rtol * want.max())
    np.testing.assert_array_equal(graph(p)[0], graph(p)[0])


def test_duplicates_cost_the_distinct_locations_and_match_naive():
    base = box_surface(300, 15)
    rng = np.random.default_rng(15)
    p = np.concatenate([base, base[rng.choice(300, 120)], base[:7]])[rng.permutation(427)]
    nb, clean = hgjax.neighbourhoods(p, "gfr"), hgjax.neighbourhoods(base, "gfr")
    copies = np.asarray(nb.first) != np.arange(len(p))
    assert copies.sum() == 127 and not (np.asarray(nb.idx)[copies] < len(p)).any()  # later copies: empty rows
    # One stored pair per location pair (the radius moves a little: copies weigh in the median).
    assert (nb.idx < len(p)).sum() <= 1.05 * (clean.idx < len(base)).sum()
    want = gfr_naive(p, 100, radius_graph.RADIUS_FACTOR)  # every copy linked to every copy
    for got in (_public(p), np.asarray(jax.jit(lambda nb: hgjax.score(nb, "gfr"))(nb))):
        np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-10 * want.max())
    soft = np.asarray(hgjax.soft_score(nb, "gfr"))
    np.testing.assert_allclose(soft / soft.max(), want / want.max(), rtol=1e-10, atol=1e-10)  # want / RMS pair length


def test_argument_errors():
    p = box_surface(50, 14)
    idx, _ = graph(p)
    cases = [
        (lambda: graph(p, variant="invarient"), ValueError, "variant"),
        (lambda: graph(p, radius_factor=-1.0), ValueError, "radius_factor"),
        (lambda: graph(p, radius_factor="2"), TypeError, "radius_factor"),
        (lambda: graph(p, variant="reference", radius_factor=2.0), ValueError, "radius_factor"),
        (lambda: graph(p, max_nn=0), ValueError, "max_nn"),
        (lambda: high_pass(p, idx[:-1]), ValueError, "idx"),
        (lambda: high_pass(p[:, :2], idx), ValueError, "points"),
        (lambda: high_pass(p, idx.astype(np.float64)), TypeError, "idx"),
        (lambda: high_pass(p, idx, weights_dtype=np.int32), TypeError, "weights_dtype"),
        (lambda: high_pass(p, idx, first=np.zeros(49, np.int32)), ValueError, "first"),
        (lambda: high_pass(p, idx, first=np.zeros(50)), ValueError, "first"),
        (lambda: high_pass(p, idx, first=[0] * 50), ValueError, "first"),
        (lambda: gfr_module.neighbourhoods(p.astype(np.int64)), TypeError, "points"),
    ]
    for call, error, name in cases:
        with pytest.raises(error, match=name):
            call()


def test_exact_sum_is_the_exact_sum_in_any_grouping():
    """GFR's weight statistics and score sum: ExactSum rounds the exact (Fraction) sum once, whatever
    the grouping of the terms, across zeros, subnormals, cancellation and the whole exponent range."""
    from fractions import Fraction

    rng = np.random.default_rng(0)
    values = np.concatenate([rng.standard_normal(3000) * 10.0 ** rng.integers(-300, 300, 3000),
                             [1e308, -1e308, 5e-324, -5e-324, 2.0**-1060, 0.0, -0.0, 1.0, 2.0**-53],
                             rng.random(3000).astype(np.float32)])
    exact = float(sum(Fraction(v) for v in values.tolist()))
    whole = hgjax.engine.select.ExactSum.of(values)
    parts = sum((hgjax.engine.select.ExactSum.of(part) for part in np.array_split(values[rng.permutation(values.size)], 7)),
                hgjax.engine.select.ExactSum())
    assert whole.value() == parts.value() == exact
    assert hgjax.engine.select.ExactSum.of(np.zeros(4)).value() == hgjax.engine.select.ExactSum.of([]).value() == 0.0


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("with_counts", [False, True])
def test_row_sums_are_the_sums_in_global_id_order(dtype, with_counts):
    """row_sums has the bits of each row's terms added one by one in global-id order, for rows whose sum is
    exact in any order (flows of one magnitude) and for rows where the order changes the rounding."""
    rng = np.random.default_rng(7)
    n, rows, k = 60, 400, 16
    tie_ext = np.append(rng.permutation(n), n)  # the padding n last
    counts_ext = np.append(rng.integers(1, 6, n).astype(np.float64), 0.0) if with_counts else None
    nbr = np.full((rows, k), n)
    flows = np.zeros((rows, k, 3), dtype)
    for i in range(rows):
        width = rng.integers(0, k + 1)
        nbr[i, :width] = rng.choice(n, width, replace=False)
        span = 3 if i % 2 else 40  # odd rows: one magnitude (exact sums); even rows: rounding depends on order
        flows[i, :width] = rng.choice([-1, 1], (width, 3)) * 2.0 ** rng.uniform(-span - 5, -5, (width, 3))
        flows[i, rng.random(k) < 0.1] = 0
    c = np.ones(n + 1) if counts_ext is None else counts_ext
    expected = np.zeros((rows, 3))
    for i in range(rows):
        for j in sorted(range(k), key=lambda col: tie_ext[nbr[i, col]]):
            expected[i] += c[nbr[i, j]] * flows[i, j].astype(np.float64)
    size = np.abs(flows)
    smallest, largest = np.where(size > 0, size, np.inf).min(axis=1), size.max(axis=1)
    got = gfr_module.row_sums(flows.transpose(0, 2, 1).copy(), smallest, largest, nbr, counts_ext, tie_ext)
    assert np.array_equal(got, expected)
    unordered = np.sum(c[nbr][..., None] * flows, axis=1, dtype=np.float64)
    assert not np.array_equal(unordered, expected)  # the order matters in some rows: the test can fail


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("with_counts", [False, True])
def test_rows_summed_on_the_device_have_the_bits_of_the_sums_in_global_id_order(dtype, with_counts):
    """laplacian_norms sums the flows on the device (float32: in any order where that is exact, else on the
    host; float64: one by one after sorting the partners): each row's norm has the bits of its flows added one
    by one in global-id order, for rows exact in any order and for rows whose partners span 2^40 in distance,
    whatever the order of the row's columns."""
    rng = np.random.default_rng(11)
    n, rows, k = 400, 300, 20
    points = rng.standard_normal((n, 3)) * 2.0 ** rng.uniform(-40, 0, (n, 1))
    points[rng.random(n) < 0.5] *= 2.0**-40  # odd rows: partners of one scale; even rows: of every scale
    tie_ext = np.append(rng.permutation(n), n)
    counts_ext = np.append(rng.integers(1, 6, n).astype(np.float64), 0.0) if with_counts else None
    own = rng.integers(0, n, rows)
    nbr = np.full((rows, k), n)
    for i in range(rows):
        pool = np.flatnonzero(np.abs(points).max(axis=1) < 2.0**-35) if i % 2 else np.arange(n)
        width = rng.integers(0, k + 1)
        nbr[i, :width] = rng.choice(pool[pool != own[i]], width, replace=False)
    args = (dtype(2.0**-20), dtype(3.0))
    got = gfr_module.laplacian_norms(points, own, nbr, None, counts_ext, tie_ext, *args, dtype, dtype)
    shuffled = np.take_along_axis(nbr, np.argsort(rng.random(nbr.shape), axis=1), axis=1)
    assert np.array_equal(gfr_module.laplacian_norms(points, own, shuffled, None, counts_ext, tie_ext, *args, dtype,
                                                     dtype), got)
    flows = _stream.map_rows(gfr_module._own_summed_flow, points, own, nbr, args=args, dtype=dtype)[0]
    flows = np.transpose(flows, (0, 2, 1)).astype(np.float64)  # the host path's flows (R, K, 3)
    c = np.ones(n + 1) if counts_ext is None else counts_ext
    lp = np.zeros((rows, 3))
    for i in range(rows):
        for j in sorted(range(k), key=lambda col: tie_ext[nbr[i, col]]):
            lp[i] += c[nbr[i, j]] * flows[i, j]
    assert np.array_equal(got, np.sqrt(lp[:, 0] * lp[:, 0] + lp[:, 1] * lp[:, 1] + lp[:, 2] * lp[:, 2]))
    unordered = np.sum(c[nbr][..., None] * flows, axis=1)
    assert not np.array_equal(unordered, lp)  # the order matters in some rows: the test can fail


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("with_counts", [False, True])
def test_pair_sums_are_the_exact_sums_of_every_pair(dtype, with_counts):
    """pair_sums of a symmetric graph: the exact (Fraction) sums of c_i c_j, c_i c_j q and c_i c_j q^2 over
    its pairs, q the kernel's; float32 counts each pair from both ends (the device's row sums, and the
    host's for rows with partners 2^40 apart, subnormal q included), float64 once."""
    rng = np.random.default_rng(13)
    n, k = 300, 12
    points = rng.standard_normal((n, 3)) * 2.0 ** rng.uniform(-40, 0, (n, 1))
    points[:4] *= 2.0**-30  # q below float32's smallest normal number
    a = rng.integers(0, n, 1500)
    a, b = np.unique(np.sort([a, (a + rng.integers(1, n, a.size)) % n], axis=0), axis=1)  # distinct pairs
    sym = gfr_module.symmetric(a, b, n, np.arange(n))
    own, tie_ext = np.arange(n), np.arange(n + 1)
    counts_ext = np.append(rng.integers(1, 6, n).astype(np.float64), 0.0) if with_counts else None
    got = [s.value() for s in gfr_module.pair_sums(points, own, sym, dtype, counts_ext, tie_ext, chunk_size=64)]
    q = gfr_module.pair_lengths(points, own, sym, dtype)
    c = np.ones(n + 1) if counts_ext is None else counts_ext
    rows, cols = np.nonzero(sym < n)
    ends = 2 if dtype == np.float32 else 1
    pairs = {}
    for i, j in zip(rows.tolist(), cols.tolist()):
        pairs[min(i, sym[i, j]), max(i, sym[i, j])] = Fraction(float(q[i, j]))
    w = {key: Fraction(float(c[key[0]] * c[key[1]])) for key in pairs}
    want = [float(ends * sum(w[key] * v**power for key, v in pairs.items())) for power in (0, 1, 2)]
    if dtype == np.float64:  # the host's terms: c q and (c q) q, each rounded as before
        want[2] = hgjax.engine.select.ExactSum.of([float(w[key]) * float(v) * float(v) for key, v in pairs.items()]).value()
    assert got == want
    assert k < sym.shape[1] and len(pairs) > 1000
    if dtype == np.float32:  # both summations ran: rows exact in any order, and rows that are not
        sums, qmin, qmax, cmax = _stream.map_rows(gfr_module._moment_kernel(with_counts), points, own, sym,
                                                  row_args=() if counts_ext is None else
                                                  (counts_ext[own][:, None] * counts_ext[sym],), dtype=dtype)
        fast = gfr_module._exact_moments(qmin, qmax, cmax, sym.shape[1])
        assert 0 < fast.sum() < n


def test_symmetric_pairs_of_int32_indices_beyond_46341_points():
    n = 50_000  # n^2 > 2^31: the packed (node, rank) keys need int64 even for int32 indices
    a = np.array([0, n - 1, 12_345], dtype=np.int32)
    b = np.array([n - 2, 3, n - 1], dtype=np.int32)
    sym = gfr_module.symmetric(a, b, n, np.arange(n))
    partners = {i: sorted(int(j) for j in sym[i] if j < n) for i in (0, 3, 12_345, n - 2, n - 1)}
    assert partners == {0: [n - 2], 3: [n - 1], 12_345: [n - 1], n - 2: [0], n - 1: [3, 12_345]}


@pytest.mark.parametrize("variant", ["invariant", "reference"])
def test_host_rows_at_a_fixed_capacity_are_the_bucketed_rows_widened(variant):
    """The public host graph is written once at the caller's width: the bucket of its fullest row, or a
    fixed ``capacity`` (the same rows, more sentinel columns); a capacity below the fullest row names it."""
    p = box_surface(600, seed=2)
    nb = hgjax.neighbourhoods(p, "gfr", variant=variant)
    width = int((np.asarray(nb.idx) < len(p)).sum(axis=1).max())
    assert nb.idx.dtype == np.int32 and nb.idx.shape == (len(p), spatial.bucket(width))
    wide = hgjax.neighbourhoods(p, "gfr", variant=variant, capacity=nb.idx.shape[1] + 5)
    np.testing.assert_array_equal(np.asarray(wide.idx)[:, :nb.idx.shape[1]], nb.idx)
    assert (np.asarray(wide.idx)[:, nb.idx.shape[1]:] == len(p)).all()
    with pytest.raises(ValueError, match=rf"capacity={width - 1} is too small: a GFR row holds {width} points"):
        hgjax.neighbourhoods(p, "gfr", variant=variant, capacity=width - 1)
