"""Multi-scale sharpness (MSS): a small learned model over rotation-invariant multi-scale
features of one k-nearest neighbourhood. Beyond the paper.

One k-nearest query of K = max(``SCALES``) points (the point itself first, then by distance)
serves every prefix k <= K. For each scale k the covariance C_k of the k nearest points has
eigenvalues l0 <= l1 <= l2 and the eigenvector n_k of l0 (the local normal). The features
(:data:`FEATURES`, F = 18) are, at every scale of ``SCALES``:

* the normalised eigenvalues e0_k = l0 / (l0 + l1 + l2) (surface variation: Pauly, Keiser,
  Gross, "Multi-scale feature extraction on point-sampled surfaces", Eurographics 2003; EA's
  score at one k) and e1_k = l1 / (l0 + l1 + l2) (with e0, the linearity, planarity and
  sphericity of Hackel, Wegner, Schindler, CVPR 2016);
* the normal high-pass h_k = |n_k . (m_k - m_low)| / r_k: m_k is the mean of the k nearest
  points (the low-pass of the k-nearest graph), m_low that of the ``LOW`` nearest (a
  denoised copy of the point, moving the pass band below the noise) and r_k = sqrt(trace
  C_k) the neighbourhood's RMS radius. The graph high-pass p - m_k (GFR's (L P)_i with
  uniform weights; Chen et al., IEEE TSP 66(3), 2018) has a normal component that is zero on
  any plane and grows with the dihedral angle at a crease;
* its tangential part t_k = |(I - n_k n_k^T)(m_k - m_low)| / r_k, large at a border or where
  the density changes;

and across scales the normals' agreement |n_8 . n_32|, |n_16 . n_32|, the radius ratios
r_8 / r_32, r_16 / r_32, and e0 at the finer scales ``FINE`` = (6, 12) (a sharp small-scale
signal where the cloud is clean). One more input is the same for every point: the cloud's noise level
(:func:`noise_of`, the root of the median e0 at ``NOISE_K`` neighbours over the seeded sample of
:func:`hgjax.neighbours.spatial.sample_ids`: a noise-aware choice of scale), so that the model can
trust the fine scales on a clean cloud and the coarse ones on a noisy cloud. A tiled run
resolves it once from the sample (:func:`resolve`, like HKC's ``d_factor``) and gives it to
every tile. The model's inputs x (F + 1,) (:func:`inputs`) give the score

    S = softplus(f(x)),   f = W3^T tanh(W2^T tanh(W1^T x + b1) + b2) + b3,

a two-hidden-layer perceptron of ``HIDDEN`` = 32 units (19 x 32 + 32 + 32 x 32 + 32 + 32 + 1
= 1,729 numbers, :mod:`hgjax.scores._mss_weights`) whose logit f estimates the log-odds that the
point lies within a spacing of a sharp edge; softplus keeps S >= 0 and strictly increasing in
f without rounding large logits to ties. Higher is sharper; resampling keeps the largest.

The model was trained by ``bench/mss_training/train_edges.py`` (plain JAX, Adam written out) on synthetic
shapes only: random polytopes, chamfered and filleted boxes, star-shaped prisms, cylinders
and cones, spheres and box unions, sampled at random and on grids, noise 0 to 1 spacing
isotropic and along the normals, randomly rotated, with the generators' exact sharp-edge
labels (:mod:`hgjax.eval.solids`). bench/edge_detectors.py reports it on the labelled
clouds, on which nothing was tuned.

Every feature is built from the covariances, means and distances of the neighbourhood, so S
does not change under rotation, translation, uniform scaling or a permutation of the points
(up to rounding and the order of tied neighbour distances; a permutation of a cloud of more
than 1000 points also changes which points the noise level is measured on).

Degenerate neighbourhoods: where all points coincide C_k = 0 and the ratios are 0; collinear
or coplanar points give finite features. The normal's derivative (:func:`eigen`) is exact
where l0 is simple and finite where it is degenerate, so gradients with respect to the points
are finite on every cloud; the score is its own smooth twin, as EA's is.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from hgjax import _exact, _method, _stream, _validate
from hgjax.neighbours import nearest, spatial
from hgjax.scores import _common, _mss_weights, ea
from hgjax.scores.eigen import jacobi

__all__ = ["FEATURES", "HIDDEN", "LOW", "NOISE_K", "SCALES", "eigen", "features", "inputs", "mlp", "neighbourhoods",
           "noise_level", "score", "sharpness", "soft_score", "weights"]

SCALES = (8, 16, 32)  # feature scales; K = max(SCALES) neighbours per query
HIDDEN = 32  # units per hidden layer of the edge model
LOW = 4  # points averaged into the denoised copy of the point
FINE = (6, 12)  # scales between SCALES' whose surface variation alone is a feature
GAP = 1e-6  # relative eigenvalue gap below which the normal's derivative leaves a term out
NOISE_K = spatial.SAMPLE_K  # neighbours of the sampled points whose surface variation measures the noise


def _prefix(offsets, valid, k: int):
    """Mean (3,) and covariance (3, 3) of the first k rows (the k nearest points)."""
    count, mean, scatter = _common.centred_scatter(offsets[:k], valid[:k])
    return mean, scatter / count


@jax.custom_jvp
def eigen(cov):
    """Eigenvalues l0 <= l1 <= l2 and a unit eigenvector n (3,) of l0 (sign arbitrary) of a
    symmetric 3 x 3 ``cov``, by one run of :mod:`hgjax.scores.eigen` 's cyclic Jacobi.

    The derivatives are first-order perturbation theory: dl_i = v_i^T dC v_i (as
    :func:`hgjax.scores.eigen.smallest_eigenvalue`) and dn = sum_j v_j (v_j^T dC n) / (l0 - l_j)
    over the other eigenpairs, with the terms of an eigenvalue within ``GAP`` x trace of l0
    left out: exact where l0 is simple, finite where it is degenerate (there n is one vector
    of its eigenspace, and the eigenspace, not n, is what varies smoothly).

    Args:
      cov: (3, 3) symmetric.

    Returns:
      (lam, n): (3,) ascending eigenvalues and (3,) unit n, in the dtype of ``cov``.

    Examples:
      >>> import jax.numpy as jnp
      >>> from hgjax.scores import mss
      >>> lam, n = mss.eigen(jnp.diag(jnp.array([2.0, 0.5, 1.0])))
      >>> lam.tolist(), n.tolist()
      ([0.5, 1.0, 2.0], [0.0, 1.0, 0.0])
    """
    lam, vec = jacobi(cov, vectors=True)
    order = _ascending(lam)
    return lam[order], vec[:, order[0]]


def _ascending(lam):
    """The indices (3,) that sort three values ascending (ties in index order), without a sort."""
    low, high = jnp.argmin(lam), 2 - jnp.argmax(lam[::-1])
    return jnp.stack([low, 3 - low - high, high])


@eigen.defjvp
def _eigen_jvp(primals, tangents):
    (cov,), (dcov,) = primals, tangents
    lam, vec = jacobi(cov, vectors=True)
    order = _ascending(lam)
    lam, vec = lam[order], vec[:, order]
    normal = vec[:, 0]
    tol = GAP * jnp.abs(jnp.trace(cov))
    dn = jnp.zeros_like(normal)
    for j in (1, 2):
        gap = lam[0] - lam[j]
        far = jnp.abs(gap) > tol
        coef = jnp.where(far, _common.matmul(vec[:, j], dcov, normal) / jnp.where(far, gap, 1), 0)
        dn = dn + coef * vec[:, j]
    dlam = jnp.stack([_common.matmul(vec[:, i], dcov, vec[:, i]) for i in range(3)])
    return (lam, normal), (dlam, dn)


FEATURES = tuple(f"{name}{k}" for k in SCALES for name in ("e0_", "e1_", "high", "tangent")) + (
    "normals8_32", "normals16_32", "radius8_32", "radius16_32") + tuple(f"e0_{k}" for k in FINE)


def features(offsets, valid):
    """The rotation-invariant multi-scale features (F,) of ONE neighbourhood (``FEATURES``).

    Args:
      offsets: (K, 3) the k nearest points minus the point, nearest first (row 0 is the
        point itself), K >= max(SCALES); padding rows masked by ``valid`` (K,).
      valid: (K,) bool.

    Returns:
      (F,) in the dtype of ``offsets``; the ratios are 0 when the valid points coincide.

    Examples:
      >>> import jax.numpy as jnp, numpy as np
      >>> from hgjax.scores import mss
      >>> x = np.random.default_rng(0).random((32, 3)); x[0] = 0
      >>> mss.features(jnp.asarray(x), jnp.ones(32, bool)).shape == (len(mss.FEATURES),)
      True
    """
    x = _common.unit_scale(jnp.where(valid[:, None], offsets, 0))
    low_mean = _prefix(x, valid, LOW)[0]
    out, normals, radii = [], [], []
    for k in SCALES:
        mean, cov = _prefix(x, valid, k)
        trace = jnp.trace(cov)
        lam, normal = eigen(cov)
        lam = jnp.maximum(lam, 0)
        shift = mean - low_mean
        along = _common.matmul(normal, shift)
        radius = _common.safe_sqrt(trace)
        out += [_common.safe_div(lam[0], trace, 0.0), _common.safe_div(lam[1], trace, 0.0),
                _common.safe_div(jnp.abs(along), radius, 0.0),
                _common.safe_div(_common.safe_sqrt(jnp.sum(jnp.square(shift - along * normal))), radius, 0.0)]
        normals.append(normal)
        radii.append(radius)
    out += [jnp.abs(_common.matmul(normals[0], normals[2])), jnp.abs(_common.matmul(normals[1], normals[2])),
            _common.safe_div(radii[0], radii[2], 0.0), _common.safe_div(radii[1], radii[2], 0.0)]
    out += [ea.variation(offsets[:k], valid[:k]) for k in FINE]
    return jnp.stack(out)


def noise_of(offsets, valid, *, real=None):
    """The noise level of a sample of neighbourhoods: sqrt of the median of their surface variation.

    On a clean surface sampled finely enough e0 = l0 / (l0 + l1 + l2) of ``NOISE_K`` nearest
    points is about 0 away from edges and corners (the median point lies on a face); noise of
    std sigma adds about sigma^2 to l0, so the square root grows about linearly with sigma over
    the spacing. One number for the whole cloud, given to every neighbourhood's model
    (:func:`inputs`) so that it can rank sharply on a clean cloud and smoothly on a noisy one.

    Args:
      offsets: (S, NOISE_K, 3) neighbourhoods minus their point, nearest first.
      valid: (S, NOISE_K) bool.
      real: (S,) bool, the sampled neighbourhoods (a prefix of the rows), or None for all.

    Returns:
      Scalar >= 0 in the dtype of ``offsets``; rotation, translation and scale invariant.

    Examples:
      >>> import jax.numpy as jnp, numpy as np
      >>> from hgjax.scores import mss
      >>> flat = np.random.default_rng(0).random((5, mss.NOISE_K, 3)) * [1, 1, 0]
      >>> float(mss.noise_of(jnp.asarray(flat), jnp.ones((5, mss.NOISE_K), bool)))
      0.0
    """
    e0 = jax.vmap(ea.variation)(offsets, valid)
    if real is None:
        return _common.safe_sqrt(jnp.median(e0))
    count = jnp.maximum(jnp.sum(real), 1)
    ranked = jnp.sort(jnp.where(real, e0, jnp.inf))
    return _common.safe_sqrt((ranked[(count - 1) // 2] + ranked[count // 2]) / 2)


_noise_of = jax.jit(noise_of)  # eager callers (noise_level, resolve) run one program, not one per operation


def noise_level(points, idx, *, count=None, lo=None):
    """The cloud's noise level (:func:`noise_of`) over the seeded sample of :func:`hgjax.neighbours.spatial.sample_ids`.

    The value the tiled path resolves once per cloud from :class:`hgjax.neighbours.spatial.SampleStats`
    (:func:`resolve`), measured here on whole-cloud neighbourhoods.

    Args:
      points: (N, 3) the cloud.
      idx: (N, K) its neighbourhoods (:func:`neighbourhoods`), the point itself first,
        padded with N; K >= ``NOISE_K``.
      count: the number of real rows of a padded cloud (:attr:`hgjax.Neighbourhoods.count`,
        traced), or None for all N.
      lo: what ``points`` round off (:attr:`hgjax.Neighbourhoods.points_lo`), or None. The
        offsets are then those of points + lo, as the tiles' sample measures them: in float64
        on the host, as exact float32 sums when traced.

    Returns:
      Scalar >= 0 in the dtype of ``points``.

    Raises:
      ValueError: ``count`` given with N > 1000 rows (the seeded sample of a traced count
        cannot be drawn; pass the noise level to the score instead).

    Examples:
      >>> import numpy as np, hgjax
      >>> from hgjax.scores import mss
      >>> flat = np.random.default_rng(0).random((500, 3)) * [1, 1, 0]
      >>> nb = hgjax.neighbourhoods(flat, "mss")
      >>> float(mss.noise_level(nb.points, nb.idx))
      0.0
    """
    n = np.shape(points)[0]
    if count is not None and n > spatial.RESOLUTION_SAMPLES:
        raise ValueError(f"the noise level of a padded cloud of more than {spatial.RESOLUTION_SAMPLES} rows needs "
                         f"noise= given; got {n} rows")
    rows = spatial.sample_ids(n)
    # Gathered on the host when concrete: the compiled program's shapes depend on the sample, not on N.
    traced = _stream.is_traced(points, idx, count, lo)
    xp = jnp if traced else np
    points, idx = xp.asarray(points), xp.asarray(idx)
    near = idx[rows, :NOISE_K]
    valid = near < n
    padded = lambda x: xp.concatenate([x, xp.zeros((1, 3), x.dtype)])  # noqa: E731  (row N: the sentinel's)
    if lo is None:
        offsets = padded(points)[near] - points[rows, None, :]
    elif traced:
        lo = jnp.asarray(lo, points.dtype)
        s, e = _exact.two_sum(padded(points)[near], -points[rows, None, :])
        offsets = s + (e + (padded(lo)[near] - lo[rows, None, :]))
    else:
        exact = points.astype(np.float64) + np.asarray(lo, np.float64)
        offsets = padded(exact)[near] - exact[rows, None, :]
    return _noise_of(xp.where(valid[..., None], offsets, 0), valid, real=None if count is None else rows < count)


def inputs(offsets, valid, noise):
    """The edge model's inputs (F + 1,) of ONE neighbourhood: :func:`features`, then the cloud's noise level.

    Args:
      offsets: (K, 3) as :func:`features`.
      valid: (K,) bool.
      noise: scalar, the cloud's :func:`noise_level`.

    Returns:
      (F + 1,) in the dtype of ``offsets``.

    Examples:
      >>> import jax.numpy as jnp, numpy as np
      >>> from hgjax.scores import mss
      >>> x = np.random.default_rng(0).random((32, 3)); x[0] = 0
      >>> mss.inputs(jnp.asarray(x), jnp.ones(32, bool), 0.25).shape == (len(mss.FEATURES) + 1,)
      True
    """
    return jnp.concatenate([features(offsets, valid), jnp.asarray(noise, offsets.dtype)[None]])


def mlp(params, x):
    """The edge model's logit: a two-hidden-layer tanh perceptron over the inputs x (F + 1,).

    Args:
      params: [W1 (F + 1, H), b1 (H,), W2 (H, H), b2 (H,), W3 (H, 1), b3 (1,)].
      x: (F + 1,) inputs (:func:`inputs`).

    Returns:
      Scalar logit.

    Examples:
      >>> import jax.numpy as jnp
      >>> from hgjax.scores import mss
      >>> params = mss.weights(jnp.float32)
      >>> mss.mlp(params, jnp.zeros(len(mss.FEATURES) + 1)).shape
      ()
    """
    w1, b1, w2, b2, w3, b3 = params
    h = jnp.tanh(_common.matmul(x, w1) + b1)
    h = jnp.tanh(_common.matmul(h, w2) + b2)
    return (_common.matmul(h, w3) + b3)[0]


def weights(dtype) -> list:
    """The shipped edge model's parameters (:mod:`hgjax.scores._mss_weights`).

    Args:
      dtype: float dtype of the arrays.

    Returns:
      [W1 (F + 1, H), b1 (H,), W2 (H, H), b2 (H,), W3 (H, 1), b3 (1,)] as JAX arrays.

    Examples:
      >>> import numpy as np
      >>> from hgjax.scores import mss
      >>> [w.shape for w in mss.weights(np.float32)][:2]
      [(19, 32), (32,)]
    """
    w = _mss_weights
    return [jnp.asarray(a, dtype) for a in (w.W1, w.B1, w.W2, w.B2, w.W3, w.B3)]


def sharpness(offsets, valid, noise):
    """MSS score of ONE neighbourhood: softplus of the edge model over :func:`inputs`.

    Args:
      offsets: (K, 3) the k nearest points minus the point, nearest first (row 0 is the
        point itself), K >= max(SCALES); padding rows masked by ``valid`` (K,).
      valid: (K,) bool.
      noise: scalar, the cloud's :func:`noise_level`.

    Returns:
      Scalar S > 0 in the dtype of ``offsets``.

    Examples:
      >>> import jax.numpy as jnp, numpy as np
      >>> from hgjax.scores import mss
      >>> g = np.stack(np.meshgrid(np.arange(-3, 3), np.arange(-3, 3), [0.0]), -1).reshape(-1, 3)
      >>> g = g[np.argsort((g ** 2).sum(1), kind="stable")]
      >>> bent = g.copy(); bent[:, 2] = np.abs(g[:, 0])  # a 90-degree crease through the point
      >>> flat, crease = (float(mss.sharpness(jnp.asarray(x), jnp.ones(36, bool), 0.0)) for x in (g, bent))
      >>> flat < crease
      True
    """
    return jax.nn.softplus(mlp(weights(offsets.dtype), inputs(offsets, valid, noise)))


def neighbourhoods(points, *, dedupe: bool = True, capacity: int | None = None, search: str = "host",
                   cell_slots: int | None = None, cell_edge=None) -> spatial.Neighbourhoods:
    """The max(SCALES) nearest points of every point (host; jittable with ``search="jax"``).

    Args:
      points: (N, 3) float32 or float64, N >= max(SCALES).
      dedupe: count exact duplicates once (default True).
      capacity: columns of ``idx`` (>= max(SCALES)); default max(SCALES).
      search: ``"host"`` (SciPy's k-d tree; not jittable) or ``"jax"`` (the traced search:
        jit, vmap, grad; the same neighbour sets, :func:`hgjax.neighbours.nearest.build`).
      cell_slots, cell_edge: the traced search's candidates read per step (static) and first
        cell edge (traced, or None from the data): speed settings, never limits.

    Returns:
      :class:`hgjax.Neighbourhoods` (no scale), the point itself first.

    Raises:
      TypeError, ValueError: invalid arguments, or N < max(SCALES).

    Examples:
      >>> import numpy as np
      >>> from hgjax.scores import mss
      >>> mss.neighbourhoods(np.random.default_rng(0).random((100, 3))).idx.shape
      (100, 32)
    """
    return nearest.build(points, max(SCALES), dedupe=dedupe, capacity=capacity, search=search,
                             cell_slots=cell_slots, cell_edge=cell_edge)


def _noise_rows(nb, noise) -> tuple:
    """The noise level (given, or :func:`noise_level` of ``nb``) once per row: the row arguments the tiles pass,
    so that one process and the tiles run the same kernel."""
    level = noise_level(nb.points, nb.idx, count=nb.count, lo=nb.points_lo) if noise is None else noise
    rows = nb.points.shape[-2]
    if _stream.is_traced(level, nb.points):
        return (jnp.full((rows,), level, nb.points.dtype),)
    return (np.full(rows, level, nb.points.dtype),)


def score(nb, *, noise=None, chunk_size: int | None = None, progress: bool = False):
    """MSS sharpness of every neighbourhood; higher is sharper.

    Args:
      nb: :class:`hgjax.Neighbourhoods` from :func:`neighbourhoods`.
      noise: the cloud's :func:`noise_level` (traced); default: measured on ``nb``.
      chunk_size: rows per streamed chunk on eager calls; never changes results.
      progress: progress bar on stderr for long eager runs.

    Returns:
      (N,) S >= 0 in the dtype of ``nb.points``.

    Examples:
      >>> import hgjax
      >>> cloud = hgjax.eval.box_union_cloud(seed=0, n_points=2000)
      >>> s = hgjax.score(hgjax.neighbourhoods(cloud.points, "mss"), "mss")
      >>> bool(s[cloud.edge_mask].mean() > 2 * s[~cloud.edge_mask].mean())
      True
    """
    return _stream.map_neighbourhoods(sharpness, nb, row_args=_noise_rows(nb, noise), chunk_size=chunk_size,
                                      progress=progress)


def soft_score(nb, *, noise=None):
    """MSS sharpness, pure JAX (its own smooth twin: :func:`score`'s kernel, streamed when called
    eagerly; finite gradients).

    Args:
      nb: :class:`hgjax.Neighbourhoods` from :func:`neighbourhoods`.
      noise: as :func:`score`.

    Returns:
      (N,) sharpness; higher is sharper.

    Examples:
      >>> import numpy as np, hgjax
      >>> nb = hgjax.neighbourhoods(np.random.default_rng(0).random((100, 3)), "mss")
      >>> hgjax.scores.mss.soft_score(nb).shape
      (100,)
    """
    return _stream.map_neighbourhoods(sharpness, nb, row_args=_noise_rows(nb, noise))


def tile_params(n: int, params: dict) -> tuple[dict, dict]:
    """Validated (build, score) parameters of MSS for a tiled run of ``n`` points; a given ``noise`` is kept
    in the build parameters, else :func:`resolve` measures it.

    Raises:
      TypeError, ValueError: invalid ``dedupe`` or ``noise``, or fewer than max(SCALES) points.
    """
    build = nearest.build_params(n, max(SCALES), params)
    if params.get("noise") is not None:
        build["noise"] = _validate.check_nonnegative(params["noise"], "noise")
    return build, {}


def resolve(build: dict, stats) -> dict:
    """The build parameters with the cloud's noise level (:func:`noise_of` of the sample's neighbourhoods)."""
    if "noise" not in build:
        sample = stats()
        build["noise"] = float(_noise_of(sample.offsets, sample.valid))
    return build


def tile_rows(index, rows, build: dict, dtype):
    """(part, idx, (noise,), reach) per batch: :func:`hgjax.neighbours.nearest.tile_rows` and the resolved noise level per row."""
    for part, idx, _, reach in nearest.tile_rows(index, rows, build, dtype):
        yield part, idx, (np.full(idx.shape[0], build["noise"], dtype),), reach


def _tile_kernel(params: dict):
    """(row kernel, narrow) the tiles stream: :func:`sharpness` on full-width rows."""
    del params  # the noise level comes per row
    return sharpness, False


METHOD = _method.Method(
    "mss", "knn", largest=True, needs_key=False,
    summary="multi-scale sharpness: a small perceptron over surface variation, eigenvalue ratios and the normal graph high-pass at 6 to 32 neighbours and the cloud's noise level, trained on synthetic shapes",
    citation="Pauly, Keiser, Gross, Eurographics 2003; Hackel, Wegner, Schindler, CVPR 2016", build=neighbourhoods, score=score,
    soft_score=soft_score,
    bytes_per_sample=4096,
    tiling=_method.Tiling(params=tile_params, reach=nearest.reach, resolve=resolve, rows=tile_rows,
                          kernel=_tile_kernel))
