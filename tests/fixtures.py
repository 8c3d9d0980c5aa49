"""Clouds the tests build, the degenerate clouds, the variants helper (one matrix per kernel), a compile counter.

Every test file takes its clouds from here, so each kind of cloud is built one way. The
variants helper runs one function of a :class:`hgjax.Neighbourhoods` the ways a JAX user
calls it (:data:`VARIANTS`: eager, jit with the neighbourhoods as an argument, jit closing
over them, vmap over a stacked batch, vmap over a ragged batch of clouds of different N) and asserts that every way gives the eager values
(dm-pix's ``chex.all_variants``). A variant maps a function and a list of neighbourhoods to
the per-cloud results, so a new way of calling is one more entry.
"""

from __future__ import annotations

import contextlib
import dataclasses

import jax
import numpy as np

import hgjax

# Agreement between the variants: XLA may fuse the traced program differently from the eager
# one, so the last bits may differ (float32 rtol 1e-5, jax-md's float32 default; float64
# 1e-12); infinities coincide.
VARIANT_RTOL = {np.dtype(np.float32): 1e-5, np.dtype(np.float64): 1e-12}
WIDEN = 5  # sentinel columns added to the ragged batch's last cloud


# ----------------------------------------------------------------------------- clouds


def uniform_cloud(n, seed=0, scale=1.0):
    """(n, 3) float64 points uniform in the cube [0, scale)^3."""
    return np.random.default_rng(seed).random((n, 3)) * scale


def normal_cloud(n, seed=0):
    """(n, 3) float64 standard normal points."""
    return np.random.default_rng(seed).normal(size=(n, 3))


def box_surface(n, seed=0, *, noise=0.0, size=(1.0, 0.8, 0.6)):
    """(n, 3) points on the surface of a box (:func:`hgjax.eval.box_surface`: sharp edges, no
    duplicates), plus Gaussian noise of standard deviation ``noise``."""
    p = hgjax.eval.box_surface(n, seed, size=size)
    return p + noise * np.random.default_rng(seed).standard_normal((n, 3)) if noise else p


def box_union(n, seed=0):
    """(n, 3) points of :func:`hgjax.eval.box_union_cloud` (a union of boxes, edge-labelled there)."""
    return hgjax.eval.box_union_cloud(seed=seed, n_points=n).points


def sphere(n, seed=0, radius=1.0):
    """(n, 3) points on the sphere of ``radius`` about the origin, uniform by area."""
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return radius * v / np.linalg.norm(v, axis=1, keepdims=True)


def grid(shape, spacing=1.0, *, seed=None):
    """(prod(shape), len(shape)) points of a rectangular lattice of ``spacing`` from the origin;
    rows shuffled by ``seed`` (None: lattice order)."""
    g = np.stack(np.meshgrid(*[np.arange(float(m)) for m in shape], indexing="ij"), axis=-1).reshape(-1, len(shape))
    g = g * spacing
    return g if seed is None else g[np.random.default_rng(seed).permutation(len(g))]


def lattice_shell(m):
    """The points of the m x m x m integer lattice on the surface of its cube."""
    g = grid((m, m, m))
    return g[((g == 0) | (g == m - 1)).any(axis=1)]


def smooth_and_rounded(n=1200, seed=3):
    """A float32 box union ("smooth") and the same rounded to 1/20 ("rounded": many equal distances and duplicates)."""
    smooth = box_union(n, seed=seed).astype(np.float32)
    return {"smooth": smooth, "rounded": (np.round(smooth * 20) / 20).astype(np.float32)}


def cloud_families(seed=0):
    """400 float64 points of each kind of cloud a traced search must treat as the host does, by name.

    smooth (a box union), quantised (the same rounded to 1/16: equal distances), lattice,
    lattice_0.1 and lattice_0.3 (a 20 x 10 x 2 grid of spacing 1/8, 0.1 or 0.3, shuffled and
    moved by whole spacings: 0.1 and 0.3 are no binary fractions, so float32 rounds the
    lattice unevenly), collinear, coplanar and tilted_plane (random in a plane through no axis).
    """
    rng = np.random.default_rng(seed)
    n = 400
    smooth = box_union(n, seed=seed)
    out = {"smooth": smooth, "quantised": np.round(smooth * 16) / 16}
    for name, spacing in (("lattice", 0.125), ("lattice_0.1", 0.1), ("lattice_0.3", 0.3)):
        out[name] = grid((20, 10, 2), spacing, seed=seed) + rng.integers(0, 3, (1, 3)) * spacing
    out["collinear"] = np.outer(np.sort(rng.random(n)), [1.0, 2.0, 3.0]) + np.array([0.3, -1.0, 2.0])
    out["coplanar"] = np.c_[rng.random((n, 2)), np.zeros(n)]
    uv = rng.random((n, 2))
    out["tilted_plane"] = uv[:, :1] * np.array([1.0, 0.3, 0.2]) + uv[:, 1:] * np.array([-0.1, 0.7, 0.9]) + 5.0
    return out


def degenerate_clouds(n=40):
    """Clouds of n points (a multiple of 4) that break naive kernels, by name.

    collinear, diagonal (on the line x = y = z: LHF's row-centred signal is 0), coplanar
    (random in a plane), planar_grid (an exact grid: symmetric neighbourhoods, HKC beta = inf),
    duplicates (n / 4 points four times), all_equal, two_points (two locations alternating).
    """
    rng = np.random.default_rng(0)
    t = np.linspace(0, 1, n)
    return {
        "collinear": np.outer(t, [1.0, 2.0, 3.0]),
        "diagonal": np.outer(t, [1.0, 1.0, 1.0]),
        "coplanar": np.c_[rng.random((n, 2)), np.zeros(n)],
        "planar_grid": np.c_[grid((4, n // 4)), np.zeros(n)],
        "duplicates": np.concatenate([rng.random((n // 4, 3))] * 4),
        "all_equal": np.full((n, 3), 0.25),
        "two_points": np.array([[0.0, 0, 0], [1, 1, 1]] * (n // 2)),
    }


# ----------------------------------------------------------------------------- variants


def widen(nb, extra):
    """``nb`` with ``extra`` more sentinel columns (the same neighbourhoods, a larger K)."""
    return dataclasses.replace(nb, idx=np.pad(nb.idx, ((0, 0), (0, extra)), constant_values=nb.points.shape[0]))


def stack(nbs):
    """A batch of equal-shape neighbourhoods (leading axis: the cloud)."""
    return jax.tree.map(lambda *x: np.stack(x), *nbs)


def _eager(fn, nbs):
    return [fn(nb) for nb in nbs]


def _one_name(fn):
    """``fn`` under one name whatever the case. A compiled module is named after its function and
    the persistent compilation cache keys on that name, so identical programs of two cases (a
    method's score and its soft twin that is the same computation, as MSS's and EA's) compile
    once in a run."""
    def variant(*args):
        return fn(*args)
    return variant


def _same_shapes(nbs):
    """The number of leading clouds whose neighbourhoods have the first cloud's shapes."""
    return next((i for i, nb in enumerate(nbs) if nb.idx.shape != nbs[0].idx.shape), len(nbs))


def _jit_argument(fn, nbs):
    """jit with the neighbourhoods as an argument, over the leading clouds of the first cloud's
    shapes: one compilation (a new N is a new program, which the ragged variant compiles)."""
    f = jax.jit(_one_name(fn))
    return [f(nb) for nb in nbs[:_same_shapes(nbs)]]


def _jit_closed_over(fn, nbs):
    """jit of a function of no argument that closes over concrete neighbourhoods (the first cloud;
    each closed-over cloud is a new compilation)."""
    nb = nbs[0]
    return [jax.jit(_one_name(lambda: fn(nb)))()]


def _vmap(fn, nbs):
    """jit(vmap) over the leading clouds that share the first cloud's shapes (plain stacking)."""
    n = _same_shapes(nbs)
    out = jax.jit(jax.vmap(_one_name(fn)))(stack(nbs[:n]))
    return [out[i] for i in range(n)]


def _ragged(fn, nbs):
    """jit(vmap) over :func:`hgjax.stack_neighbourhoods` of every cloud, the last one widened by
    ``WIDEN`` sentinel columns (N and K differ), each cloud's result cut to its own rows; the
    padding rows must be 0 (scores) or weigh 0."""
    out = np.asarray(jax.jit(jax.vmap(_one_name(fn)))(hgjax.stack_neighbourhoods([*nbs[:-1], widen(nbs[-1], WIDEN)])))
    counts = [nb.points.shape[0] for nb in nbs]
    assert all((out[i, n:] == 0).all() for i, n in enumerate(counts)), "a padding row is not 0"
    return [out[i, :n] for i, n in enumerate(counts)]


VARIANTS = {"eager": _eager, "jit_argument": _jit_argument, "jit_closed_over": _jit_closed_over, "vmap": _vmap,
            "ragged": _ragged}


def assert_close(got, want, rtol, atol=None, err_msg=""):
    """Same dtype and shape, infinities at the same places, finite values within ``rtol`` and
    ``atol`` (default ``rtol * 1e-3``)."""
    got, want = np.asarray(got), np.asarray(want)
    assert got.dtype == want.dtype and got.shape == want.shape, (err_msg, got.dtype, got.shape, want.dtype, want.shape)
    np.testing.assert_array_equal(np.isinf(got), np.isinf(want), err_msg=err_msg)
    f = np.isfinite(want)
    np.testing.assert_allclose(got[f], want[f], rtol=rtol, atol=rtol * 1e-3 if atol is None else atol, err_msg=err_msg)


def assert_variants_agree(fn, nbs, *, rtol=None, atol=None):
    """Run ``fn(nb)`` in every variant of :data:`VARIANTS`; each equals eager.

    Args:
      fn: a function of one :class:`hgjax.Neighbourhoods` returning an array.
      nbs: two or more neighbourhoods of one dtype; the first two of the same shapes (the plain
        vmap batch), any others of other sizes (the ragged batch holds them all).
      rtol: relative tolerance; default :data:`VARIANT_RTOL` of the points' dtype.
      atol: absolute tolerance; default ``rtol * 1e-3``.

    Returns:
      The eager results, one per cloud, as NumPy arrays.
    """
    dtype = np.dtype(nbs[0].points.dtype)
    rtol = VARIANT_RTOL[dtype] if rtol is None else rtol
    want = [np.asarray(x) for x in _eager(fn, nbs)]
    assert all(w.dtype == dtype for w in want), [w.dtype for w in want]
    for name, variant in VARIANTS.items():
        if name == "eager":
            continue
        for i, got in enumerate(variant(fn, nbs)):
            assert_close(got, want[i], rtol, atol, err_msg=f"variant {name}, cloud {i}")
    return want


# ----------------------------------------------------------------------------- compilations

@contextlib.contextmanager
def backend_compiles():
    """Counts XLA backend compilations inside the block (jax.monitoring event listener)."""
    events = []

    def listener(event, duration, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            events.append(kwargs.get("fun_name", event))

    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        yield events
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)
