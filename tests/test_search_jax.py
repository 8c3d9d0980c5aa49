"""hgjax.neighbours.cells: the traced search gives the host builder's neighbour sets, exactly.

Every cloud is padded to one size (``count`` marks its real rows), so one compiled search
serves every cloud of a case: the padded path is the one under test everywhere.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hgjax.neighbours import cells as search
from hgjax.neighbours import balls, nearest, spatial

from fixtures import box_surface, degenerate_clouds, lattice_shell, sphere, uniform_cloud

ROWS = 1024  # every test cloud is padded to this many rows
K = 16
SLOTS = 16  # candidates read per step: small, so most blocks are read in several steps


def clouds():
    """The fixture clouds by name, each at most ROWS points."""
    box = box_surface(700, seed=1)
    out = {
        "random": uniform_cloud(800, seed=2),
        "quantised_1mm": np.round(box_surface(900, seed=3) * 1000) / 1000,  # many exact ties
        "duplicated": np.concatenate([box[:200]] * 4)[np.random.default_rng(4).permutation(800)],
        "mixed_density": np.concatenate([sphere(700, seed=5, radius=0.3), uniform_cloud(150, seed=6) * 4 - 2]),
        "lattice": lattice_shell(9),
        "georeferenced": box + np.array([512345.0, 4012345.0, 210.0]),  # float32 keeps ~3 cm there
    }
    degenerate = degenerate_clouds(40)
    out.update({name: degenerate[name] for name in ("collinear", "coplanar", "all_equal", "duplicates",
                                                      "two_points", "planar_grid")})
    return out


CLOUDS = clouds()


def padded(p, dtype):
    """(ROWS, 3) ``p`` in ``dtype`` followed by copies of its first point, and its count."""
    p = np.asarray(p, dtype)
    return np.concatenate([p, np.repeat(p[:1], ROWS - len(p), axis=0)]), np.int32(len(p))


def cut(idx, n):
    """The first n rows of a padded result, the padded sentinel ROWS as the cloud's own n."""
    idx = np.asarray(idx)
    assert (idx[n:] == ROWS).all(), "a padding row lists a neighbour"
    idx = idx[:n]
    return np.where(idx < n, idx, n)


@functools.lru_cache(maxsize=None)
def traced_knn(k, dedupe, x64, metric="l2"):
    """One jitted search per case (``radius`` inf: no bound; one program with and without)."""
    fn = jax.jit(lambda p, count, radius: search.traced_knn(p, k, dedupe=dedupe, slots=SLOTS, count=count,
                                                     radius=radius, metric=metric))
    return lambda p, count, radius=np.inf: fn(p, count, radius)


@functools.lru_cache(maxsize=None)
def traced_within(columns, metric, dedupe, max_count, x64):
    return jax.jit(lambda p, h, count: search.within(p, h, columns=columns, metric=metric, dedupe=dedupe,
                                                     max_count=max_count, slots=SLOTS, count=count))


# float64 under x64 (the host's arithmetic, bit for bit) and float32 without x64 (exact pairs);
# float32 input under x64 is upcast to the first: the vmap test checks it against the host.
X64_CASES = [pytest.param(True, np.float64, id="x64-f64"), pytest.param(False, np.float32, id="f32-pairs")]


def x64_mode(on):
    return jax.enable_x64(on)


# ----------------------------------------------------------------------------- kNN == host
@pytest.mark.full
@pytest.mark.parametrize("dedupe", [False, True], ids=["all", "dedupe"])
@pytest.mark.parametrize("x64,dtype", X64_CASES)
def test_knn_equals_the_host_on_every_cloud(x64, dtype, dedupe):
    fn = traced_knn(K, dedupe, x64)
    for name, p in CLOUDS.items():
        if name == "georeferenced" and not x64:
            continue  # the search then runs on the float32 input: the host's float64 frame is finer
        q = np.asarray(p, dtype)
        want = nearest.knn(q, K, dedupe=dedupe).idx
        with x64_mode(x64):
            found = fn(*padded(q, dtype))
        assert not bool(found.overflow), name
        np.testing.assert_array_equal(cut(found.idx, len(q)), want, err_msg=name)


def test_knn_distances_are_the_hosts_bits():
    p = CLOUDS["quantised_1mm"]
    index = spatial.SpatialIndex(spatial.local_frame(p)[0])
    dist, _ = index.nearest(slice(None), K)
    with x64_mode(True):
        found = traced_knn(K, False, True)(*padded(p, np.float64))
    got = np.asarray(found.dist)[:len(p)]
    np.testing.assert_array_equal(np.sort(got, axis=1), np.sort(index.to_caller(dist), axis=1))
    np.testing.assert_array_equal(np.asarray(found.reach)[:len(p)], got[:, -1])


@pytest.mark.parametrize("metric", ["l2", "l2sq", "linf"])
@pytest.mark.parametrize("scale", [1e150, 1e-138])
def test_knn_at_the_ends_of_float64_equals_the_host(scale, metric):
    """x64: keys near 1e301 or 1e-276 (squared), beyond float32's range, still rank as the host's."""
    p = CLOUDS["quantised_1mm"] * scale
    with x64_mode(True):
        found = traced_knn(K, False, True, metric)(*padded(p, np.float64))
    assert not bool(found.overflow)
    np.testing.assert_array_equal(cut(found.idx, len(p)), naive_rows(p, K, metric))


def naive_rows(p, k, metric="l2", radius=None, dedupe=False):
    """Brute force: every pair's key as the host computes it (float64 local frame, x + y + z in order), rows
    by (key, index), the point itself first; radius: keep keys below it."""
    p = spatial.local_frame(p)[0]  # the host's float64 frame
    n = len(p)
    d = p[:, None, :] - p[None]
    if metric == "linf":
        key = np.abs(d).max(-1)
    else:
        key = (d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]) + d[..., 2] * d[..., 2]
        key = key if metric == "l2sq" else np.sqrt(key)
    first = np.array([np.flatnonzero((p == p[i]).all(axis=1))[0] for i in range(n)]) if dedupe else np.arange(n)
    key = np.where((first != np.arange(n))[None, :], np.inf, key)  # only first copies are candidates
    key[np.arange(n), first] = -1.0  # the point itself (its location's first copy) first
    key = key[first]  # every copy asks its first copy's query
    order = np.lexsort((np.broadcast_to(np.arange(n), key.shape), key), axis=1)[:, :k]
    keep = np.take_along_axis(key, order, axis=1)
    ok = np.isfinite(keep) if radius is None else np.isfinite(keep) & (keep < radius)
    return np.where(ok, order, n)


@pytest.mark.full
@pytest.mark.parametrize("metric", ["l2", "l2sq", "linf"])
def test_knn_metrics_and_radius_match_brute_force(metric):
    """GFR's capped radius graph: the k nearest by squared distance (then index) closer than r."""
    p = CLOUDS["quantised_1mm"][:300]
    r = {"l2": 0.06, "l2sq": 0.06 ** 2, "linf": 0.05}[metric]
    with x64_mode(True):
        found = traced_knn(K, True, True, metric)(*padded(p, np.float64), radius=r)
        plain = traced_knn(K, True, True, metric)(*padded(p, np.float64))
    np.testing.assert_array_equal(cut(found.idx, len(p)), naive_rows(p, K, metric, radius=r, dedupe=True))
    np.testing.assert_array_equal(cut(plain.idx, len(p)), naive_rows(p, K, metric, dedupe=True))


# ----------------------------------------------------------------------------- balls and cubes == host
def host_within(p, h, norm, dedupe, max_count):
    """The host's rows (caller order, sentinel n) and radii of SpatialIndex.cube."""
    index = spatial.SpatialIndex(spatial.local_frame(p)[0], dedupe=dedupe)
    idx, half = index.cube(np.asarray(h, np.float64)[index.order], max_count=max_count, norm=norm)
    return index.caller_idx(idx), index.to_caller(half)


@pytest.mark.full
@pytest.mark.parametrize("metric,max_count", [("l2", 24), ("linf", None)], ids=["ball-max24", "cube"])
@pytest.mark.parametrize("x64,dtype", X64_CASES)
def test_within_equals_the_host(x64, dtype, metric, max_count):
    """HKC/HKF's queries: the invariant ball (max_count shrink) and the reference cube, per-point radii."""
    columns = 128
    fn = traced_within(columns, metric, True, max_count, x64)
    for name in ("random", "quantised_1mm", "duplicated", "mixed_density", "lattice", "all_equal"):
        q = np.asarray(CLOUDS[name], dtype)
        spacing = spatial.intrinsic_resolution(q, robust=True) or 1.0
        h = (2.0 * spacing * (1 + 0.5 * np.random.default_rng(0).random(len(q)))).astype(dtype if x64 else np.float32)
        want, radii = host_within(q, h, 2 if metric == "l2" else np.inf, True, max_count)
        with x64_mode(x64):
            found = fn(padded(q, dtype)[0], np.pad(h, (0, ROWS - len(q)), mode="edge"), np.int32(len(q)))
        assert not bool(found.overflow), name
        got = cut(found.idx, len(q))
        width = max(got.shape[1], want.shape[1])
        pad = lambda a: np.pad(a, ((0, 0), (0, width - a.shape[1])), constant_values=len(q))  # noqa: B023, E731
        np.testing.assert_array_equal(pad(got), pad(want), err_msg=name)
        if x64:
            np.testing.assert_array_equal(np.asarray(found.reach)[:len(q)], radii, err_msg=name)


@pytest.mark.full
def test_hkc_invariant_neighbourhoods_compose_to_the_hosts_bits():
    """HKC/HKF's default build: the spacing from 17 nearest distinct points (NumPy's pairwise mean,
    float64), the ball of sqrt(3) k / 2 f times it, shrunk below 256 points; the same bits."""
    factor = np.sqrt(3.0) * 3 / 2 * 1.6
    with x64_mode(True):
        spacing = jax.jit(lambda p, c: balls.local_spacing(search.traced_knn(p, 17, dedupe=True, slots=SLOTS,
                                                                       count=c)))
        ball = traced_within(256, "l2", True, 256, True)  # a sparse point's ball holds up to 255
        for name in ("quantised_1mm", "duplicated", "mixed_density", "georeferenced"):
            p = CLOUDS[name]
            index = spatial.SpatialIndex(spatial.local_frame(p)[0], dedupe=True)
            want_s, want_r = (index.to_caller(x) for x in spatial.local_spacing(index, np.arange(index.n), 16))
            want, radii = host_within(p, factor * want_s, 2, True, 256)
            s, r = spacing(*padded(p, np.float64))
            np.testing.assert_array_equal(np.asarray(s)[:len(p)], want_s, err_msg=name)
            np.testing.assert_array_equal(np.asarray(r)[:len(p)], want_r, err_msg=name)
            found = ball(padded(p, np.float64)[0], factor * s, np.int32(len(p)))
            assert not bool(found.overflow), name
            got = cut(found.idx, len(p))
            np.testing.assert_array_equal(got[:, :want.shape[1]], want, err_msg=name)
            assert (got[:, want.shape[1]:] == len(p)).all()
            np.testing.assert_array_equal(np.asarray(found.reach)[:len(p)], radii, err_msg=name)


# ----------------------------------------------------------------------------- jit, vmap, grad
@pytest.mark.full
def test_jit_equals_eager():
    p = CLOUDS["quantised_1mm"][:64].astype(np.float32)
    eager = search.traced_knn(p, 8, dedupe=True, slots=8)
    jitted = jax.jit(lambda p: search.traced_knn(p, 8, dedupe=True, slots=8))(p)
    np.testing.assert_array_equal(eager.idx, jitted.idx)
    np.testing.assert_array_equal(eager.dist, jitted.dist)
    assert not bool(eager.overflow)


@pytest.mark.full
def test_vmap_over_a_padded_batch_equals_the_loop():
    """A batch of clouds of different sizes, padded with per-cloud counts; and equal-N clouds."""
    names = ("random", "duplicated", "collinear")
    fn = traced_knn(K, True, True)
    with x64_mode(True):
        batch = [padded(CLOUDS[name], np.float32) for name in names]
        points, counts = np.stack([b[0] for b in batch]), np.array([b[1] for b in batch])
        found = jax.jit(jax.vmap(lambda p, c: search.traced_knn(p, K, dedupe=True, slots=SLOTS, count=c)))(
            points, counts)
        assert found.idx.shape == (3, ROWS, K) and not np.asarray(found.overflow).any()
        for i, name in enumerate(names):
            np.testing.assert_array_equal(found.idx[i], fn(*batch[i]).idx, err_msg=name)
            np.testing.assert_array_equal(cut(found.idx[i], len(CLOUDS[name])),
                                          nearest.knn(CLOUDS[name].astype(np.float32), K, dedupe=True).idx)
        same = np.stack([uniform_cloud(300, seed=s) for s in (7, 8)])
        stacked = jax.jit(jax.vmap(lambda p: search.traced_knn(p, 8)))(same)
        assert not np.asarray(stacked.overflow).any()
        for i in range(2):
            np.testing.assert_array_equal(stacked.idx[i], nearest.knn(same[i], 8).idx)


@pytest.mark.full
def test_gradients_flow_through_the_points_not_the_choice():
    p = jnp.asarray(CLOUDS["random"][:300])

    def spread(p):
        found = search.traced_knn(p, 8)
        nbr = p[found.idx]  # (N, 8, 3); every row is full here
        return jnp.sum((nbr - p[:, None, :]) ** 2), found.idx

    with x64_mode(True):
        grad, idx = jax.jit(jax.grad(spread, has_aux=True))(p)
        fixed = jax.grad(lambda q: jnp.sum((q[idx] - q[:, None, :]) ** 2))(p)
    assert np.isfinite(grad).all()
    np.testing.assert_allclose(grad, fixed, rtol=1e-12)


# ----------------------------------------------------------------------------- overflow, never truncation
@pytest.mark.full
def test_blocks_are_read_whole_however_few_slots_and_a_small_edge_is_flagged_and_grown():
    p = CLOUDS["random"][:300]
    want = nearest.knn(p, 8).idx
    with x64_mode(True):
        fn = jax.jit(lambda p, e: search.traced_knn(p, 8, slots=2, edge=e, spill=0))
        dense = fn(p, 0.4)  # blocks of about 200 points, read two at a time
        assert not bool(dense.overflow)
        np.testing.assert_array_equal(dense.idx, want)
        tiny = fn(p, 1e-3)
        assert bool(tiny.overflow) and bool(tiny.uncovered) and float(tiny.edge_needed) > 1e-3
        wider = search.grown(search.traced_knn, p, 8, slots=2, edge=1e-3, spill=0)  # the edge grows
        assert not bool(wider.overflow) and float(wider.edge) > 1e-3
        np.testing.assert_array_equal(wider.idx, want)


@pytest.mark.full
def test_rows_missed_by_the_edge_are_searched_again_under_jit():
    """An edge too small for some rows: wider levels redo them (no overflow); with no spill
    they are reported."""
    p = CLOUDS["mixed_density"]
    want = nearest.knn(p, K).idx
    with x64_mode(True):
        fn = jax.jit(lambda p, e: search.traced_knn(p, K, slots=SLOTS, edge=e, spill=400))
        found = fn(p, 0.3)  # right for the dense sphere, too small for the sparse points around it
        assert not bool(found.overflow) and float(found.edge) == 0.3
        np.testing.assert_array_equal(found.idx, want)
        none = jax.jit(lambda p, e: search.traced_knn(p, K, slots=SLOTS, edge=e, spill=0))(p, 0.3)
        assert bool(none.overflow) and bool(none.uncovered) and float(none.edge_needed) > 0.3


@pytest.mark.full
def test_within_reports_the_columns_needed_and_grows_them():
    p = CLOUDS["lattice"]
    h = np.full(len(p), 2.5)
    want, _ = host_within(p, h, np.inf, False, None)
    with x64_mode(True):
        narrow = jax.jit(lambda p, h: search.within(p, h, columns=8, metric="linf", slots=SLOTS))(p, h)
        assert bool(narrow.overflow) and int(narrow.columns_needed) == want.shape[1]
        found = search.grown(search.within, p, h, columns=8, metric="linf")
    assert not bool(found.overflow) and found.idx.shape[1] >= want.shape[1]
    np.testing.assert_array_equal(found.idx[:, :want.shape[1]], want)
    assert (np.asarray(found.idx)[:, want.shape[1]:] == len(p)).all()


@pytest.mark.full
def test_a_sparse_2km_tile_needs_no_dense_grid():
    """Patches 10 cm apart in a 2 km x 2 km tile: a dense grid of 8 cm cells would hold 6e8 cells."""
    rng = np.random.default_rng(9)
    centres = rng.random((6, 2)) * 2000.0
    patches = [np.c_[c + rng.random((400, 2)) * 2.0, rng.normal(size=400) * 0.01] for c in centres]
    p = np.concatenate(patches) + np.array([700000.0, 5600000.0, 300.0])
    want = nearest.knn(p, K).idx
    with x64_mode(True):
        found = search.grown(search.traced_knn, p, K)
    assert float(found.edge) < 1.0
    np.testing.assert_array_equal(found.idx, want)


def test_invalid_arguments_raise():
    p = np.zeros((10, 3), np.float32)
    with pytest.raises(ValueError, match=r"shape \(N, 3\)"):
        search.traced_knn(np.zeros((10, 2)), 4)
    with pytest.raises(ValueError, match="unknown metric"):
        search.traced_knn(p, 4, metric="l1")
    with pytest.raises(ValueError, match="slots"):
        jax.jit(lambda p: search.traced_knn(p, 4, slots=0))(p)
