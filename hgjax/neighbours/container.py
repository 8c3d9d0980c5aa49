"""The padded neighbourhoods of a cloud, the one currency between host and kernels.

:class:`Neighbourhoods` is a frozen, registered JAX pytree (its method and build parameters
static, :func:`record`); :func:`stack_neighbourhoods` pads the neighbourhoods of clouds of any
N and K into one batch for ``jax.vmap``. The builders that fill it live in
:mod:`hgjax.neighbours.spatial` (the host's k-d tree, which re-exports these names),
:mod:`hgjax.engine._pipeline` (per method) and the traced search. This module builds on nothing of
hgjax but :mod:`hgjax._validate`.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from hgjax import _validate

__all__ = ["Neighbourhoods", "record", "stack_neighbourhoods"]


@functools.partial(jax.tree_util.register_dataclass, data_fields=["points", "idx", "scale", "first", "count", "overflow", "points_lo"],
                   meta_fields=["method", "params"])
@dataclasses.dataclass(frozen=True)
class Neighbourhoods:
    """Padded neighbourhoods of a cloud: the one currency between host and kernels.

    A registered JAX pytree: pass it to jitted functions, stack a batch of clouds for
    ``jax.vmap`` with :func:`stack_neighbourhoods` ((B, N, 3) points, (B, N, K) idx; clouds of
    any N and K padded, with a per-cloud ``count``), differentiate with respect to its
    points. Masks are derived (``idx < N``, ``row < count``), not stored. Build it on the host
    with :func:`hgjax.neighbourhoods` (per method) or :func:`hgjax.knn` / :func:`hgjax.cube`.

    Attributes:
      points: (N, 3) float coordinates in a local frame (see :func:`hgjax.local_frame`).
      idx: (N, K) int32 neighbour indices into ``points``, padded with the sentinel N.
        K is static: a new K compiles a new kernel.
      scale: (N,) per-point length of the method (the voxel spacing d of HKC/HKF), or None.
      first: (N,) int32 index of the first point at each point's location, or None (every
        point its own location). Set by GFR's invariant graph, which links distinct
        locations once (the rows of later copies are empty) and weighs each by its number
        of points.
      count: int32 scalar, the number of real points of a padded cloud (its first
        ``count`` rows; the rows after them are padding that no neighbourhood lists and
        every score treats as absent), or None (every row is a real point). Set by
        :func:`stack_neighbourhoods`; traced, so one compiled kernel serves every count.
      method: the method whose builder made these neighbourhoods (static), or None for the
        generic builders :func:`hgjax.knn` and :func:`hgjax.cube`.
      params: the build parameters as given (defaults filled, data-dependent ones such as
        HKC's ``d_factor`` left None so that clouds built alike stack into one batch), as
        sorted ``(name, value)`` pairs (static): :func:`hgjax.score` refuses a method or a
        parameter that disagrees with them.
      overflow: int32 scalar from the traced search (``search="jax"``): 0 (a traced build
        that overflows raises instead: :func:`hgjax.neighbourhoods`), or None from the host
        search.
      points_lo: (N, 3) what ``points`` round off where the local frame is finer than their
        dtype (float64 coordinates run in float32), or None (nothing rounded off). The
        kernels read each offset as (p_j - p_i) + (lo_j - lo_i): to the working precision
        wherever the frame's origin lies, and the same bits as a tile of the same points. It
        follows no change of ``points`` (``dataclasses.replace(nb, points=...)`` keeps it:
        pass ``points_lo=None`` with points of another cloud).

    Examples:
      >>> import numpy as np, hgjax
      >>> nb = hgjax.Neighbourhoods(np.zeros((2, 3)), np.array([[0, 2], [1, 0]], np.int32))
      >>> nb.mask.tolist()
      [[True, False], [True, True]]
    """

    points: np.ndarray
    idx: np.ndarray
    scale: np.ndarray | None = None
    first: np.ndarray | None = None
    count: np.ndarray | None = None
    method: str | None = None
    params: tuple = ()
    overflow: np.ndarray | None = None
    points_lo: np.ndarray | None = None

    @property
    def mask(self):
        """(N, K) bool, True where ``idx`` names a real neighbour."""
        return self.idx < self.points.shape[-2]

    @property
    def row_mask(self):
        """(N,) bool, True for the rows of real points: all rows unless ``count`` is set."""
        n = self.points.shape[-2]
        if self.count is None:
            return np.ones(self.points.shape[:-1], dtype=bool)
        count = jnp.asarray(self.count)
        return jax.lax.broadcasted_iota(count.dtype, count.shape + (n,), count.ndim) < count[..., None]


def stack_neighbourhoods(nbs) -> Neighbourhoods:
    """One padded batch of the neighbourhoods of clouds of any N and K, for ``jax.vmap`` (host, not jittable).

    Cloud b is padded from N_b to N_max rows and from K_b to K_max columns: its real rows
    and indices are unchanged, the sentinel N_b becomes N_max (every padding column stays
    padding), padding rows list no neighbour and are listed by none, their points are
    copies of the cloud's first point (no degenerate geometry), their ``scale`` a copy of
    its first scale and their ``first`` their own row. ``count`` records N_b, so under
    ``jax.vmap`` :func:`hgjax.score`, :func:`hgjax.soft_score`, :func:`hgjax.soft_weights`
    and :func:`hgjax.soft_select` (``valid=nb.row_mask``) treat the padding rows as absent:
    a cloud's first N_b scores are its own, its padding rows score 0, weigh 0 and get zero
    gradients. A new N_max or K_max compiles a new kernel; pass ``capacity=`` to the builder
    for a fixed K, and pad to a few fixed N_max to bound compilations.

    Args:
      nbs: a non-empty sequence of :class:`Neighbourhoods` of single clouds (points (N_b, 3)),
        built for the same method with the same parameters, in one float dtype. An item
        that already has a ``count`` contributes its first ``count`` rows.

    Returns:
      :class:`Neighbourhoods` with points (B, N_max, 3), idx (B, N_max, K_max) int32 padded
      with N_max, scale (B, N_max) or None, first (B, N_max) int32 or None (None when no
      cloud has one), count (B,) int32, and the clouds' method and params.

    Raises:
      TypeError: ``nbs`` is not a sequence of Neighbourhoods, or their dtypes differ.
      ValueError: ``nbs`` is empty, an item is already a batch or holds no point (or 2^24 or
        more), or their methods, build parameters or the presence of ``scale`` differ.

    Examples:
      >>> import jax, numpy as np, hgjax
      >>> clouds = [hgjax.eval.box_surface(n, seed=0) for n in (300, 450)]
      >>> nbs = [hgjax.neighbourhoods(p, "ea") for p in clouds]
      >>> batch = hgjax.stack_neighbourhoods(nbs)
      >>> batch.points.shape, batch.idx.shape, batch.count.tolist()
      ((2, 450, 3), (2, 450, 16), [300, 450])
      >>> f = jax.jit(jax.vmap(lambda nb: (hgjax.score(nb, "ea"), hgjax.soft_weights(nb, 0.2, method="ea"))))
      >>> scores, w = f(batch)
      >>> bool(np.allclose(scores[0, :300], hgjax.score(nbs[0], "ea"), rtol=1e-6))
      True
      >>> np.round(w.sum(axis=1), 3).tolist(), float(w[0, 300:].max())
      ([60.0, 90.0], 0.0)
    """
    clouds = [_real_rows(nb) for nb in _validate.check_neighbourhood_list(nbs, Neighbourhoods)]
    n_max = max(c.points.shape[0] for c in clouds)
    k_max = max(c.idx.shape[1] for c in clouds)
    with_first = any(c.first is not None for c in clouds)
    with_lo = any(c.points_lo is not None for c in clouds)
    points, idx, scale, first, lo = [], [], [], [], []
    for c in clouds:
        n, pad = c.points.shape[0], n_max - c.points.shape[0]
        points.append(np.concatenate([c.points, np.repeat(c.points[:1], pad, axis=0)]))
        if with_lo:
            own_lo = np.zeros_like(c.points) if c.points_lo is None else c.points_lo
            lo.append(np.concatenate([own_lo, np.repeat(own_lo[:1], pad, axis=0)]))
        rows = np.where(c.idx < n, c.idx, n_max)
        idx.append(np.pad(rows, ((0, pad), (0, k_max - rows.shape[1])), constant_values=n_max))
        if c.scale is not None:
            scale.append(np.concatenate([c.scale, np.repeat(c.scale[:1], pad)]))
        if with_first:
            own = np.arange(n_max, dtype=np.int32)
            first.append(own if c.first is None else np.concatenate([c.first, own[n:]]).astype(np.int32))
    return Neighbourhoods(np.stack(points), np.stack(idx).astype(np.int32), np.stack(scale) if scale else None,
                          np.stack(first) if with_first else None,
                          np.array([c.points.shape[0] for c in clouds], dtype=np.int32),
                          method=clouds[0].method, params=clouds[0].params, points_lo=np.stack(lo) if with_lo else None)


def _real_rows(nb: Neighbourhoods) -> Neighbourhoods:
    """``nb`` on the host, cut to its first ``count`` rows when it is padded (sentinel: the count)."""
    n = nb.points.shape[0] if nb.count is None else int(nb.count)
    cut = lambda x: None if x is None else np.asarray(x)[:n]  # noqa: E731
    idx = cut(nb.idx)
    return dataclasses.replace(nb, points=cut(nb.points), idx=np.where(idx < n, idx, n), scale=cut(nb.scale),
                               first=cut(nb.first), count=None, points_lo=cut(nb.points_lo))


def record(params: dict) -> tuple:
    """Build parameters as the sorted, hashable ``(name, value)`` pairs a Neighbourhoods keeps."""
    return tuple(sorted((k, tuple(v) if isinstance(v, list) else v) for k, v in params.items()))
