"""The public pieces of a resample: neighbourhoods -> score -> keep, and their soft twins.

* :func:`neighbourhoods` (host, SciPy, not jittable) builds exactly what a method needs;
* :func:`score` (pure JAX: jit, vmap) and its differentiable twin :func:`soft_score`;
* :func:`keep` (host) turns scores into indices; :func:`soft_weights` into keep weights.

On one tile, :func:`hgjax.resample` (:mod:`hgjax.engine`) is
``keep(score(neighbourhoods(points, method), method), ratio)``, streamed tile by tile.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from hgjax import _validate
from hgjax.neighbours import backend, spatial
from hgjax._method import Method
from hgjax.engine._registry import DEFAULT, METHODS, scoring, split
from hgjax.engine.select import soft_select, top_k

__all__ = ["capacity", "keep", "neighbourhoods", "score", "soft_resample", "soft_score", "soft_weights"]

def neighbourhoods(points, method: str, **params) -> spatial.Neighbourhoods:
    """The neighbourhoods a method scores, built on the host with SciPy, or traced (``search="jax"``).

    With ``search="jax"`` (the methods whose build parameters list ``search``: the k-nearest
    ones, HKC/HKF's cubes and GFR's graph) the build is pure JAX: it runs under ``jax.jit`` and
    ``jax.vmap`` and inside ``jax.grad``, with the host's neighbour sets and no sizes to pass: the
    k-nearest search reads every candidate its cells hold. Only a ball's or a graph row's
    static columns (``capacity``) can be outgrown; eagerly they are sized to the cloud
    (``nb.idx.shape[-1]``; :func:`capacity` counts them without a build); under ``jit`` a row
    wider than them stops the program with an error naming the ``capacity`` needed, never a
    truncated result.

    Build once per cloud, then call :func:`score` or :func:`soft_score` as often as needed,
    inside your own ``jit``, ``vmap`` or ``grad``. Parameters another stage takes (e.g.
    ``solver`` of LHF's score) are accepted and ignored here, so the same ``**params`` can be
    passed to every stage.

    Args:
      points: (N, 3) float32 or float64; never modified.
      method: a scoring method of :data:`METHODS` (a :class:`Method`).
      **params: the method's neighbourhood parameters (e.g. ``variant``, ``d_factor``,
        ``lengths``, ``k``, ``dedupe``, ``capacity``: a fixed K so that a batch of clouds can
        share one shape; a cloud that needs more raises, naming the capacity it needs).

    Returns:
      :class:`hgjax.Neighbourhoods`: points (N, 3) in a local frame and the working dtype,
      idx (N, K) int32 padded with N, and the per-point scale the method needs.

    Raises:
      TypeError, ValueError: invalid points, method or parameters.

    Examples:
      >>> import numpy as np, hgjax
      >>> nb = hgjax.neighbourhoods(np.random.default_rng(0).random((500, 3)), "lhf")
      >>> nb.idx.shape, nb.idx.dtype
      ((500, 16), dtype('int32'))
    """
    entry = scoring(method)
    nb = entry.build(points, **split(entry, "build", params))
    return dataclasses.replace(nb, method=method)


def capacity(points, method: str, **params) -> int:
    """The columns (``capacity``) a traced build of ``method`` needs for these points, counted by the host search.

    The allocation of a jitted update: under ``jax.jit`` a ball (HKC/HKF) or a graph row (GFR)
    of ``search="jax"`` has static columns, and one wider than them stops the program with an
    error naming the capacity needed. This counts them directly, without compiling anything:
    the host's build of the same neighbourhoods (SciPy's k-d tree; the traced search's sets),
    its fullest row rounded up to a power of two (at least 8), the shape bucket of
    :func:`neighbourhoods`, or what the method's traced search reads where that is wider
    (:attr:`hgjax.Method.traced_columns`: GFR's reference ball). The k-nearest methods need no
    sizing: their capacity is their k.

    Args:
      points: (N, 3) float32 or float64; never modified.
      method: a scoring method of :data:`METHODS`.
      **params: the method's neighbourhood parameters, as :func:`neighbourhoods` takes them
        (``search`` and parameters of other stages are ignored).

    Returns:
      The columns to pass as ``capacity=`` to a jitted build, score or resample of clouds like these.

    Raises:
      TypeError, ValueError: invalid points, method or parameters (as :func:`neighbourhoods`).

    Examples:
      >>> import jax, numpy as np, hgjax
      >>> p = hgjax.eval.box_union_cloud(seed=0, n_points=2000).points.astype(np.float32)
      >>> cols = hgjax.capacity(p, "hkc")
      >>> nb = jax.jit(lambda q: hgjax.neighbourhoods(q, "hkc", search="jax", capacity=cols))(p)
      >>> nb.idx.shape == (2000, cols), bool((np.asarray(nb.idx) == hgjax.neighbourhoods(p, "hkc").idx).all())
      (True, True)
    """
    entry = scoring(method)
    build = {k: v for k, v in split(entry, "build", params).items() if k != "search"}
    nb = entry.build(points, **build)
    width = nb.idx.shape[-1]
    if entry.traced_columns is not None:
        width = max(width, spatial.bucket(entry.traced_columns(_validate.check_points(points), nb)))
    return int(width)


_CHECKS = {"kernel_size": _validate.check_kernel_size, "lengths": _validate.check_lengths}


def _matching(nb, entry: Method, stage: str, params: dict) -> dict:
    """``params`` of ``stage`` with the build parameters ``nb`` records filled in; a mismatch raises.

    Neighbourhoods built for another method (other than one sharing its builder, such as
    HKC and HKF), or with a different value of a parameter that the stage also takes (LHF's
    ``lengths``, HKC's ``kernel_size``), are refused instead of silently mis-scored.
    """
    if not isinstance(nb, spatial.Neighbourhoods):
        raise TypeError(f"nb must be hgjax.Neighbourhoods (from hgjax.neighbourhoods); got {type(nb).__name__}")
    if nb.method is not None and METHODS[nb.method].build is not entry.build:
        raise ValueError(f"nb was built for method {nb.method!r}; method {entry.name!r} needs its own"
                         f" neighbourhoods: hgjax.neighbourhoods(points, {entry.name!r})")
    built = dict(nb.params)
    out = dict(params)
    for name in entry.params[stage] & entry.params["build"]:
        if name not in built or built[name] is None:
            continue
        if name in out:
            out[name] = _CHECKS.get(name, lambda v: v)(out[name])  # a bad value is named as such first
        given = out.setdefault(name, built[name])
        if (tuple(given) if isinstance(given, list) else given) != built[name]:
            raise ValueError(f"{name}={given!r} disagrees with the neighbourhoods, built with {name}={built[name]!r};"
                             f" rebuild them with hgjax.neighbourhoods(points, {entry.name!r}, {name}={given!r})")
    return out


def score(nb: spatial.Neighbourhoods, method: str, **params) -> jax.Array:
    """Per-point scores of a method on prebuilt neighbourhoods, pure JAX.

    Scores never depend on the ratio (LHF's two-length combination, Eqs. (15)-(16), is part
    of its selection: :func:`keep`). Runs inside a caller's ``jax.jit`` (``method`` and
    shape-setting parameters static; float parameters traced, so a sweep does not
    recompile) and under
    ``jax.vmap`` over a batch of clouds (:func:`hgjax.stack_neighbourhoods`). Called eagerly,
    it streams fixed-size chunks through one compiled kernel, so a new cloud size does not
    recompile.

    Args:
      nb: :class:`hgjax.Neighbourhoods` from :func:`neighbourhoods` with the same method
        and parameters.
      method: a scoring method of :data:`METHODS`.
      **params: the method's score parameters (e.g. ``variant``, ``lengths``).

    Returns:
      (N,) scores in the dtype of ``nb.points``, or (N, C) with C =
      ``METHODS[method].columns`` (LHF: gamma at each of its two lengths, Eq. (14));
      ``METHODS[method].largest`` says which end is kept. A padded cloud of a stacked batch
      (``nb.count`` set) scores its first ``count`` rows as the cloud alone and its padding
      rows 0.

    Raises:
      TypeError: a ``ratio`` (it belongs to :func:`keep` and :func:`resample`), or invalid
        parameters.
      ValueError: invalid method or parameters; neighbourhoods whose ``overflow`` is set (under
        ``jit`` when the program runs).

    Examples:
      >>> import jax, numpy as np, hgjax
      >>> nb = hgjax.neighbourhoods(np.random.default_rng(0).random((500, 3)), "hkc")
      >>> jax.jit(lambda nb: hgjax.score(nb, "hkc"))(nb).shape
      (500,)
    """
    entry = scoring(method)
    _ratio_free("score", params)
    backend.check(nb)
    return _absent_zero(nb, entry.score(nb, **_matching(nb, entry, "score", split(entry, "score", params))))


def _ratio_free(stage: str, params: dict) -> None:
    """Raise TypeError when a score stage is given a ratio: scores never depend on it."""
    if "ratio" in params:
        raise TypeError(f"{stage} takes no ratio: scores are ratio-free (LHF's two lengths are combined when"
                        " the points are kept); pass the ratio to hgjax.keep, hgjax.resample or hgjax.soft_weights")


def _absent_zero(nb: spatial.Neighbourhoods, values):
    """``values`` (N,) or (N, C) with the padding rows of a stacked cloud (row >= ``nb.count``) set to 0."""
    if nb.count is None:
        return values
    return jnp.where(nb.row_mask.reshape(nb.row_mask.shape + (1,) * (values.ndim - nb.row_mask.ndim)), values, 0)


def soft_score(nb: spatial.Neighbourhoods, method: str, **params) -> jax.Array:
    """Differentiable twin of :func:`score`: smooth per-point scores, pure JAX.

    ``jax.grad`` with respect to ``nb.points`` and the float parameters (``tau``) is finite, also on duplicate, collinear, coplanar and all-equal clouds.

    Args:
      nb: :class:`hgjax.Neighbourhoods` from :func:`neighbourhoods`.
      method: a scoring method of :data:`METHODS`.
      **params: the method's soft-score parameters (``tau`` for HKC/HKF/LHF,
        ``kernel_size``, ``lengths``).

    Returns:
      (N,) smooth scores, or (N, C) as :func:`score`; ``METHODS[method].largest`` says which
      end is kept. Padding rows of a stacked cloud (``nb.count`` set) score 0, with zero
      gradients.

    Raises:
      TypeError: a ``ratio`` (it belongs to :func:`soft_weights`), or invalid parameters.
      ValueError: invalid method or parameters.

    Examples:
      >>> import dataclasses, jax, numpy as np, hgjax
      >>> nb = hgjax.neighbourhoods(np.random.default_rng(0).random((200, 3)), "ea")
      >>> g = jax.grad(lambda p: hgjax.soft_score(dataclasses.replace(nb, points=p), "ea").sum())(nb.points)
      >>> bool(np.isfinite(g).all())
      True
    """
    entry = scoring(method)
    _ratio_free("soft_score", params)
    backend.check(nb)
    return _absent_zero(nb, entry.soft_score(nb, **_matching(nb, entry, "soft_score",
                                                             split(entry, "soft_score", params))))


def keep(scores, ratio: float | None = None, *, method: str, count: int | None = None, key=None,
         **params) -> np.ndarray:
    """Indices of the points a method keeps, from its scores (host): ``count`` of them, or ceil(ratio N).

    The kept count m enters the selection directly: LHF ranks the combination of its two
    columns (Eqs. (15)-(16), :func:`hgjax.scores.lhf.combine`) whose order statistics are
    taken at m.

    Args:
      scores: (N,) scores from :func:`score` for this method, or (N, C) for a method with
        C = ``METHODS[method].columns`` (LHF).
      ratio: fraction alpha in (0, 1]; or give ``count``.
      method: a scoring method of :data:`METHODS`.
      count: the number kept, in [1, N]; or give ``ratio``.
      key: ``jax.random`` key for methods that sample (GFR's default mode).
      **params: the method's selection parameters (``mode`` for GFR, ``n_clusters`` for
        PCA-AC).

    Returns:
      (M,) int64 unique indices, M = ``count`` or ceil(ratio N), highest keep priority first
      (ties by index).

    Raises:
      TypeError: ``scores`` is None or not a float array; both or neither of ``ratio`` and
        ``count``; invalid key or parameters.
      ValueError: ``scores`` is not (N,) (or (N, C)) with N >= 1 or holds NaN; invalid ratio,
        count, method or parameters. The same checks for every method.

    Examples:
      >>> import numpy as np, hgjax
      >>> hgjax.keep(np.array([0.3, 0.1, 0.2, 0.4]), 0.5, method="hkc").tolist()
      [1, 2]
      >>> hgjax.keep(np.array([[0.2, 0.1], [0.4, 0.3], [0.1, 0.2]]), count=1, method="lhf").tolist()
      [1]
    """
    entry = scoring(method)
    values = _validate.check_scores(scores, columns=entry.columns)
    m = _validate.check_keep(values.shape[0], ratio, count)
    return kept(entry, values, m, key, split(entry, "select", params))


def kept(entry: Method, values: np.ndarray, m: int, key, chosen: dict) -> np.ndarray:
    """:func:`keep` of validated (N,) or (N, C) scores ``values``, the count ``m`` and selection parameters ``chosen``."""
    if entry.combine is not None:
        values = entry.combine(values, m)
    if entry.select is None:
        return top_k(values, m, largest=entry.largest)
    return entry.select(values, m, key=key, **chosen)


def soft_weights(nb: spatial.Neighbourhoods, ratio, *, method: str, temperature=0.05, **params) -> jax.Array:
    """Per-point keep weights, pure JAX: ``soft_select(soft_score(nb, method), ratio)``.

    LHF's two soft-score columns are combined first (:func:`hgjax.scores.lhf.combine`,
    Eqs. (15)-(16)) at the kept count ceil(ratio N), as :func:`keep` does.

    Jit with ``method`` and shape parameters static; ``nb.points``, ``ratio``,
    ``temperature`` and ``tau`` are traced (gradients flow to all of them). vmap over a
    batch of clouds (:func:`hgjax.stack_neighbourhoods`).

    Args:
      nb: :class:`hgjax.Neighbourhoods` from :func:`neighbourhoods` (same method).
      ratio: fraction alpha in (0, 1].
      method: a scoring method of :data:`METHODS`.
      temperature: softness of the selection, in score units (> 0).
      **params: soft-score parameters (see :func:`soft_score`).

    Returns:
      (N,) weights in [0, 1] summing to ratio * N; for a padded cloud of a stacked batch,
      to ratio * ``nb.count``, its padding rows weighing exactly 0 (zero gradients).

    Raises:
      TypeError, ValueError: as :func:`soft_score` and :func:`hgjax.soft_select`.

    Examples:
      >>> import numpy as np, hgjax
      >>> nb = hgjax.neighbourhoods(np.random.default_rng(0).random((100, 3)), "hkc")
      >>> round(float(hgjax.soft_weights(nb, 0.2, method="hkc").sum()), 6)
      20.0
    """
    entry = scoring(method)
    s = soft_score(nb, method, **params)
    if entry.combine is not None:
        n = nb.points.shape[0] if nb.count is None else nb.count
        s = entry.combine(s, _validate.n_keep_any(n, ratio), count=nb.count)
    return soft_select(s, ratio, temperature=temperature, largest=entry.largest,
                       valid=None if nb.count is None else nb.row_mask)


def soft_resample(points, ratio: float, *, method: str = DEFAULT, temperature=0.05, **params) -> jax.Array:
    """Differentiable soft resampling of a concrete cloud: per-point keep weights.

    ``soft_weights(neighbourhoods(points, method), ratio)``. The neighbourhoods are built on
    the host, so ``points`` must be concrete; inside your own ``jit`` or ``grad``, build
    them once with :func:`neighbourhoods` and call :func:`soft_weights`.

    Args:
      points: (N, 3) float32 or float64 (validated: finite, enough points).
      ratio: fraction alpha in (0, 1].
      method: a scoring method of :data:`METHODS`.
      temperature: soft top-k temperature, in score units (> 0).
      **params: neighbourhood and soft-score parameters.

    Returns:
      (N,) weights in [0, 1] in the working dtype, summing to ratio * N.

    Raises:
      TypeError: ``points`` is a tracer, or a parameter has the wrong type.
      ValueError: invalid points, ratio, temperature, tau or method.

    Examples:
      >>> import numpy as np, hgjax
      >>> w = hgjax.soft_resample(np.random.default_rng(0).random((100, 3)), 0.2, method="ea")
      >>> w.shape
      (100,)
    """
    if not _validate.is_concrete(points):
        raise TypeError("soft_resample builds neighbourhoods on the host and needs concrete points;"
                        " inside jit or grad, build nb = hgjax.neighbourhoods(points, method) outside"
                        " and call hgjax.soft_weights(nb, ratio, method=method) inside")
    pts = _validate.check_points(points)
    ratio = _validate.check_ratio(ratio)
    _validate.check_traced_positive(temperature, "temperature")
    entry = scoring(method)
    nb = neighbourhoods(pts, method, **params)
    return soft_weights(nb, ratio, method=method, temperature=temperature,
                        **{k: v for k, v in params.items() if k in entry.params["soft_score"]})
