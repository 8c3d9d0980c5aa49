"""The public JAX API: score under jit / vmap / host streaming, the Neighbourhoods pytree, validation.

Host path = ``hgjax.score`` on concrete neighbourhoods (fixed-size chunks streamed through one
compiled kernel); traced path = the same call inside the caller's ``jax.jit`` or ``jax.vmap``.
The variants matrix (tests/fixtures.py) holds every score, soft score and soft weights to
eager == jit(argument) == jit(closed-over) == vmap, within fixtures.VARIANT_RTOL.
"""

from __future__ import annotations

import functools
import subprocess
import sys
import textwrap

import jax
import numpy as np
import pytest

import fixtures
import hgjax

N = 300
CAPACITY = 128  # fixed K of a batch: enough for every method on these clouds

# Every scoring method and variant (PCA-AC scores with EA's score): (method, static params, traced float params).
SCORE_CASES = [
    ("hkc", {}, {}),
    ("hkc", {"variant": "reference"}, {}),
    ("hkf", {}, {}),
    ("hkf", {"variant": "reference"}, {}),
    ("lhf", {}, {}),
    ("lhf", {"solver": "eigh"}, {}),
    ("lhf", {"variant": "reference"}, {}),
    ("gfr", {}, {}),
    ("gfr", {"variant": "reference"}, {}),
    ("ea", {}, {}),
    ("mss", {}, {}),
]
CASE_IDS = ["-".join([m, *map(str, s.values())]) for m, s, _ in SCORE_CASES]
SCORING = sorted(m for m, e in hgjax.METHODS.items() if isinstance(e, hgjax.Method))


def cloud(seed=0, n=N, dtype=np.float64):
    """A noisy box surface (sharp edges, no duplicates)."""
    return fixtures.box_surface(n, seed, noise=0.005).astype(dtype)


def path_rtol(method, static, dtype):
    """GFR's reference variant keeps its weights in float32 (as the authors' code): float32 tolerance."""
    reference_gfr = method == "gfr" and static.get("variant") == "reference"
    return fixtures.VARIANT_RTOL[np.dtype(np.float32) if reference_gfr else np.dtype(dtype)]


def host_score(nb, method, **params):
    """hgjax.score on concrete neighbourhoods (the host-streamed path) as a NumPy array."""
    return np.asarray(hgjax.score(nb, method, **params))


# ----------------------------------------------------------------- the variants matrix


# The registry gives HKF HKC's soft score and PCA-AC EA's neighbourhoods and scores: their
# matrices would repeat those.
SAME_SOFT = {"hkf": "hkc", "pca_ac": "ea"}
SOFT_WEIGHTS = ("hkc", "lhf")


def kernel_cases():
    """(id, method, build params, fn(nb)) of every score, soft score and soft weights."""
    cases = []
    for (method, static, floats), case_id in zip(SCORE_CASES, CASE_IDS):
        cases.append((f"score-{case_id}", method, static,
                      functools.partial(hgjax.score, method=method, **static, **floats)))
    for method in sorted(set(SCORING) - set(SAME_SOFT)):
        cases.append((f"soft_score-{method}", method, {}, functools.partial(hgjax.soft_score, method=method)))
    # soft_weights = soft_select(soft_score): a method that keeps the smallest scores and one that
    # keeps the largest and combines its two soft-score columns at the ratio (Eqs. (15)-(16)).
    for method in SOFT_WEIGHTS:
        cases.append((f"soft_weights-{method}", method, {},
                      functools.partial(hgjax.soft_weights, ratio=0.2, method=method)))
    return cases


KERNEL_CASES = kernel_cases()


def test_shared_soft_scores_are_the_same_functions():
    for method, twin in SAME_SOFT.items():
        assert hgjax.METHODS[method].soft_score is hgjax.METHODS[twin].soft_score
        assert hgjax.METHODS[method].largest is hgjax.METHODS[twin].largest
    assert hgjax.METHODS["pca_ac"].score is hgjax.METHODS["ea"].score
    assert hgjax.METHODS["pca_ac"].build is hgjax.METHODS["ea"].build


@pytest.mark.full
@pytest.mark.parametrize("method,static,fn", [c[1:] for c in KERNEL_CASES], ids=[c[0] for c in KERNEL_CASES])
def test_variants_agree(method, static, fn, dtype):
    """eager == jit(argument) == jit(closed-over) == vmap over a batch == vmap over a ragged batch
    (a third cloud, smaller, with exact duplicates and more columns), in float32 and float64."""
    capacity = None if hgjax.METHODS[method].kind == "knn" else CAPACITY  # a batch shares one K
    third = cloud(3, n=N - 81, dtype=dtype)
    clouds = [cloud(1, dtype=dtype), cloud(2, dtype=dtype), np.concatenate([third, third[:20]])]  # 20 duplicates
    nbs = [hgjax.neighbourhoods(c, method, capacity=capacity, **static) for c in clouds]
    rtol = path_rtol(method, static, dtype)
    # Weights lie in [0, 1] and soft_select's threshold moves them all: an absolute tolerance.
    atol = rtol if fn.func is hgjax.soft_weights else None
    want = fixtures.assert_variants_agree(fn, nbs, rtol=rtol, atol=atol)
    columns = None if fn.func is hgjax.soft_weights else hgjax.METHODS[method].columns
    row = () if columns is None else (columns,)
    assert [w.shape for w in want] == [(N, *row), (N, *row), (N - 61, *row)]
    assert not any(np.isnan(w).any() for w in want)


@pytest.mark.full
def test_lhf_score_is_ratio_free_and_its_soft_weights_trace_the_ratio():
    nb = hgjax.neighbourhoods(cloud(), "lhf")
    gamma = host_score(nb, "lhf")
    assert gamma.shape == (N, 2)
    np.testing.assert_array_equal(gamma, np.asarray(hgjax.scores.lhf.single(nb, lengths=(8, 16))))
    for stage in (hgjax.score, hgjax.soft_score):
        with pytest.raises(TypeError, match="takes no ratio.*hgjax.keep, hgjax.resample"):
            stage(nb, "lhf", ratio=0.2)
    f = jax.jit(lambda nb, ratio: hgjax.soft_weights(nb, ratio, method="lhf"))
    a, b = f(nb, 0.2), f(nb, 0.5)
    assert f._cache_size() == 1  # a new ratio did not recompile
    np.testing.assert_allclose([float(a.sum()), float(b.sum())], [0.2 * N, 0.5 * N], rtol=1e-6)
    np.testing.assert_allclose(b, hgjax.soft_weights(nb, 0.5, method="lhf"), rtol=1e-9, atol=1e-12)


@pytest.mark.full
@pytest.mark.parametrize("method,static,floats", [
    ("hkc", {}, {}), ("hkf", {"variant": "reference"}, {}), ("lhf", {}, {}), ("ea", {}, {})])
def test_host_path_is_chunk_size_invariant_bitwise(method, static, floats):
    nb = hgjax.neighbourhoods(cloud(4, n=2500), method, **static)
    base = host_score(nb, method, **static, **floats)  # one 8192-row chunk
    np.testing.assert_array_equal(host_score(nb, method, chunk_size=1000, **static, **floats), base)  # 3 chunks


@pytest.mark.full
def test_lhf_eigh_kernels_finish_on_default_chunks_and_under_vmap():
    """The eigh-based LHF kernels (reference variant, eigh solver): the eager default 8192-row
    chunk (8 blocks in one lax.map) and jit(vmap) over a batch must finish and agree.

    Runs in a subprocess so that a deadlock fails the test instead of hanging the suite.
    """
    code = textwrap.dedent("""
        import jax, numpy as np, hgjax
        jax.config.update("jax_enable_x64", True)
        for params in ({"variant": "reference"}, {"solver": "eigh"}):
            nbs = [hgjax.neighbourhoods(hgjax.eval.box_surface(300, s), "lhf", **params) for s in range(3)]
            f = jax.jit(lambda nb: hgjax.score(nb, "lhf", **params))
            one = [np.asarray(f(nb)) for nb in nbs]
            for nb, want in zip(nbs, one):
                np.testing.assert_allclose(np.asarray(hgjax.score(nb, "lhf", **params)), want, rtol=1e-12)
            stacked = jax.tree.map(lambda *x: np.stack(x), *nbs)
            np.testing.assert_allclose(np.asarray(jax.jit(jax.vmap(f))(stacked)), np.stack(one), rtol=1e-12)
        print("done")
    """)
    try:
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    except subprocess.TimeoutExpired:
        pytest.fail("an eigh-based LHF score hung (over 120 s; normally ~10 s): eager default chunk or jit(vmap) batch")
    assert out.returncode == 0 and "done" in out.stdout, out.stderr[-2000:]


# ----------------------------------------------------------------- Neighbourhoods pytree


def test_neighbourhoods_pytree_round_trip_and_derived_mask():
    nb = hgjax.neighbourhoods(cloud(), "hkc")
    leaves, treedef = jax.tree_util.tree_flatten(nb)
    assert len(leaves) == 3  # points, idx, scale; the mask is not stored
    back = jax.tree_util.tree_unflatten(treedef, leaves)
    assert isinstance(back, hgjax.Neighbourhoods)
    for a, b in zip((nb.points, nb.idx, nb.scale), (back.points, back.idx, back.scale)):
        np.testing.assert_array_equal(a, b)
    doubled = jax.tree.map(lambda x: 2 * x, nb)
    np.testing.assert_array_equal(doubled.idx, 2 * nb.idx)
    np.testing.assert_array_equal(nb.mask, nb.idx < N)
    assert nb.mask.any(axis=1).all() and not nb.mask.all()  # padding exists, every row holds its point
    no_scale = hgjax.neighbourhoods(cloud(), "lhf")
    assert no_scale.scale is None and len(jax.tree_util.tree_leaves(no_scale)) == 2


def test_hkc_neighbourhoods_have_scale_and_no_padding_beyond_the_bucket():
    nb = hgjax.neighbourhoods(cloud(), "hkc")
    assert nb.points.shape == (N, 3) and nb.idx.dtype == np.int32
    assert nb.scale.shape == (N,) and (nb.scale > 0).all()
    fullest = int(nb.mask.sum(axis=1).max())
    assert nb.idx.shape[1] == max(8, 1 << (fullest - 1).bit_length())  # next power of two, >= 8
    assert (nb.idx[~nb.mask] == N).all()  # the sentinel N pads


@pytest.mark.parametrize("method", SCORING)
def test_capacity_too_small_names_the_capacity_needed(method):
    p = cloud()
    free = hgjax.neighbourhoods(p, method)
    needed = int(free.mask.sum(axis=1).max())
    with pytest.raises(ValueError, match=rf"capacity.*{needed}"):
        hgjax.neighbourhoods(p, method, capacity=needed - 1)
    fixed = hgjax.neighbourhoods(p, method, capacity=needed + 5)
    assert fixed.idx.shape == (N, needed + 5)
    np.testing.assert_array_equal(fixed.mask.sum(axis=1), free.mask.sum(axis=1))


# ----------------------------------------------------------------- validation


UNKNOWN_METHOD = (ValueError, "unknown method 'nope'")
UNKNOWN_PARAMETER = (TypeError, "bogus")


@pytest.mark.parametrize("call, error", [
    (lambda nb: hgjax.score(nb, "nope"), UNKNOWN_METHOD),
    (lambda nb: hgjax.soft_score(nb, "nope"), UNKNOWN_METHOD),
    (lambda nb: hgjax.neighbourhoods(nb.points, "nope"), UNKNOWN_METHOD),
    (lambda nb: hgjax.keep(np.zeros(3), 0.5, method="nope"), UNKNOWN_METHOD),
    (lambda nb: hgjax.soft_weights(nb, 0.5, method="nope"), UNKNOWN_METHOD),
    (lambda nb: hgjax.score(nb, "fps"), (ValueError, "'fps' is a sampler")),
    (lambda nb: hgjax.score(nb, "ea", bogus=1), UNKNOWN_PARAMETER),
    (lambda nb: hgjax.soft_score(nb, "ea", bogus=1), UNKNOWN_PARAMETER),
    (lambda nb: hgjax.neighbourhoods(nb.points, "ea", bogus=1), UNKNOWN_PARAMETER),
    (lambda nb: hgjax.soft_weights(nb, 0.5, method="ea", bogus=1), UNKNOWN_PARAMETER),
    (lambda nb: hgjax.resample(nb.points, 0.5, method="ea", bogus=1), UNKNOWN_PARAMETER),
])
def test_unknown_methods_and_parameters_raise_naming_them(call, error):
    nb = hgjax.neighbourhoods(cloud(n=40), "ea")
    with pytest.raises(error[0], match=error[1]):
        call(nb)


def test_soft_score_rejects_tau_for_gfr():
    nb = hgjax.neighbourhoods(cloud(n=40), "gfr")
    with pytest.raises(TypeError, match="tau"):
        hgjax.soft_score(nb, "gfr", tau=0.1)
