"""Dense recovery of a resampled cloud and the recovery metrics (paper section IV-C).

The paper rebuilds a dense cloud from a sparse, edge-heavy resampled cloud in two steps: an
alpha complex of the kept points for six alpha values, then Poisson-disk sampling of each
surface. Of the six recoveries it keeps the one with the most original points within
``d_theta = 3 * resolution`` of the original cloud (REFERENCE.md, "Evaluation protocol").

Everything here runs on the host (SciPy's Delaunay triangulation, trimesh's surface sampler,
the k-d tree of :mod:`hgjax.neighbours.spatial`); nothing is jittable.

Conventions for degenerate input, which never raise from inside SciPy:

* Fewer than 4 kept points, or kept points that are all coplanar or collinear (no
  tetrahedron), give an empty recovery: ``points`` of shape (0, 3), no faces, ``alpha = 0.0``
  and ``status`` ``"too_few_points"`` or ``"flat"``.
* An alpha value for which no tetrahedron is small enough gives no surface; when that
  happens for every alpha the recovery is empty with ``status = "empty"``.
* :func:`recovery_metrics` of a direction without any pair closer than ``d_theta`` reports
  the distance ``d_theta`` itself (the largest distance a counted pair could have) and a
  count of 0, so metrics of an empty recovery are finite and rank last.
"""

from __future__ import annotations

from typing import NamedTuple, Sequence

import numpy as np
import trimesh
from scipy.spatial import Delaunay, QhullError

from hgjax import _validate
from hgjax.neighbours.spatial import SpatialIndex, intrinsic_resolution

__all__ = [
    "ALPHA_FACTORS",
    "D_THETA_FACTOR",
    "Recovery",
    "alpha_complex",
    "recover",
    "recovery_metrics",
]

ALPHA_FACTORS = (4.0, 8.0, 16.0, 32.0, 64.0, 128.0)
"""The six default alpha values, in units of the ORIGINAL cloud's intrinsic resolution."""

D_THETA_FACTOR = 3.0
"""d_theta = 3 x the original cloud's intrinsic resolution (paper section IV-C)."""

# The four triangles of a tetrahedron (a, b, c, d), each listed with the vertex it omits.
_TETRA_FACES = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])


class Recovery(NamedTuple):
    """A dense cloud recovered from a resampled one.

    Attributes:
      points: (M, 3) recovered points in the kept points' float dtype; M is at most
        ``n_samples`` and 0 for an empty recovery.
      vertices: (V, 3) the kept points, the vertices of the surface.
      faces: (F, 3) int64 boundary triangles of the chosen alpha complex, indices into
        ``vertices``, oriented away from their tetrahedron; (0, 3) when empty.
      alpha: the chosen alpha (a length, not a factor); 0.0 when the recovery is empty.
      n_within: N1 of the chosen recovery, the number of original points closer than
        ``d_theta`` to it.
      status: ``"ok"``, or why the recovery is empty: ``"too_few_points"`` (fewer than 4
        kept points), ``"flat"`` (kept points coplanar or collinear) or ``"empty"`` (no
        alpha kept a tetrahedron).

    Examples:
      >>> import numpy as np, hgjax
      >>> empty = hgjax.eval.recover(np.zeros((3, 3)), np.random.default_rng(0).random((50, 3)))
      >>> empty.status, empty.points.shape
      ('too_few_points', (0, 3))
    """

    points: np.ndarray
    vertices: np.ndarray
    faces: np.ndarray
    alpha: float
    n_within: int
    status: str

    @property
    def mesh(self) -> trimesh.Trimesh:
        """The chosen surface as a ``trimesh.Trimesh`` (unprocessed, unused vertices kept)."""
        return trimesh.Trimesh(vertices=self.vertices, faces=self.faces, process=False)


def _circumradii(points: np.ndarray, simplices: np.ndarray) -> np.ndarray:
    """Circumradius of each tetrahedron, inf for a flat one (float64)."""
    p = points[simplices].astype(np.float64)
    u, v, w = (p[:, 1] - p[:, 0]), (p[:, 2] - p[:, 0]), (p[:, 3] - p[:, 0])
    vw, wu, uv = np.cross(v, w), np.cross(w, u), np.cross(u, v)
    num = ((u * u).sum(1)[:, None] * vw + (v * v).sum(1)[:, None] * wu
           + (w * w).sum(1)[:, None] * uv)
    det = 2.0 * (u * vw).sum(1)
    scale = np.maximum.reduce([(u * u).sum(1), (v * v).sum(1), (w * w).sum(1)]) ** 1.5
    flat = np.abs(det) <= 1e-12 * scale
    out = np.full(len(simplices), np.inf)
    out[~flat] = np.linalg.norm(num[~flat], axis=1) / np.abs(det[~flat])
    return out


def _boundary(points: np.ndarray, simplices: np.ndarray) -> np.ndarray:
    """Triangles that belong to exactly one of ``simplices``, oriented away from it."""
    if simplices.shape[0] == 0:
        return np.empty((0, 3), np.int64)
    tri = simplices[:, _TETRA_FACES].reshape(-1, 3)
    opposite = simplices.reshape(-1)  # the vertex each face omits
    key = np.sort(tri, axis=1)
    order = np.lexsort(key.T[::-1])
    key = key[order]
    group = np.cumsum(np.r_[True, (key[1:] != key[:-1]).any(axis=1)]) - 1
    keep = np.sort(order[np.bincount(group)[group] == 1])
    tri, opposite = tri[keep], opposite[keep]
    p = points.astype(np.float64)
    a, b, c = p[tri[:, 0]], p[tri[:, 1]], p[tri[:, 2]]
    inward = (np.cross(b - a, c - a) * (p[opposite] - a)).sum(1) > 0
    tri[inward] = tri[inward][:, ::-1]
    return tri.astype(np.int64)


def _delaunay(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, str]:
    """Delaunay tetrahedra and their circumradii, or a status for degenerate input."""
    if points.shape[0] < 4:
        return np.empty((0, 4), np.int64), np.empty(0), "too_few_points"
    try:
        simplices = Delaunay(points.astype(np.float64)).simplices.astype(np.int64)
    except QhullError:  # all points coplanar or collinear: no tetrahedron exists
        return np.empty((0, 4), np.int64), np.empty(0), "flat"
    radii = _circumradii(points, simplices)
    return simplices, radii, "ok" if np.isfinite(radii).any() else "flat"


def alpha_complex(points, alpha: float) -> np.ndarray:
    """Boundary triangles of the alpha complex of a cloud (tetrahedra only).

    The Delaunay tetrahedra (``scipy.spatial.Delaunay``) whose circumradius is below
    ``alpha`` are kept; a triangle is on the boundary when exactly one kept tetrahedron has
    it as a face (this includes faces of the convex hull). Isolated triangles and edges of
    the full alpha complex are not produced, so a single sheet of points sampled on an open
    surface gives no triangles: only volumes are recovered.

    Args:
      points: (N, 3) float32 or float64.
      alpha: circumradius threshold, a length > 0.

    Returns:
      (F, 3) int64 indices into ``points``, each triangle oriented away from its kept
      tetrahedron. (0, 3) when N < 4, when the points are coplanar, or when no tetrahedron
      is smaller than ``alpha``.

    Raises:
      TypeError, ValueError: for invalid points or alpha.

    Examples:
      >>> import numpy as np, hgjax
      >>> corners = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
      >>> hgjax.eval.alpha_complex(corners, 1.0).shape
      (4, 3)
      >>> hgjax.eval.alpha_complex(corners, 0.5).shape  # circumradius is sqrt(3)/2
      (0, 3)
    """
    pts = _validate.check_points(points)
    alpha = _validate.check_positive(alpha, "alpha")
    simplices, radii, _ = _delaunay(pts)
    return _boundary(pts, simplices[radii < alpha])


def _nearest(reference: np.ndarray, query: np.ndarray, d_theta: float) -> np.ndarray:
    """Distance from each query point to ``reference``, inf where it is d_theta or more."""
    if reference.shape[0] == 0:
        return np.full(query.shape[0], np.inf)
    dist = SpatialIndex(reference).tree.query(query, 1, d_theta)[0][:, 0]
    return np.where(dist < d_theta, dist, np.inf)


def _summary(d_orig: np.ndarray, d_rec: np.ndarray, d_theta: float) -> dict:
    """The four metrics from the two arrays of thresholded nearest distances."""
    near_o, near_r = np.isfinite(d_orig), np.isfinite(d_rec)
    d0 = float(d_orig[near_o].mean()) if near_o.any() else d_theta
    dual = float(d_rec[near_r].mean()) if near_r.any() else d_theta
    return {"D0": d0, "dual": dual, "mean": 0.5 * (d0 + dual), "N1": int(near_o.sum()),
            "N2": int(near_r.sum())}


def recovery_metrics(original, recovered, *, d_theta: float) -> dict:
    """Distance, dual distance and matched counts between an original and a recovered cloud.

    Pairs farther apart than ``d_theta`` are ignored (paper Eqs. (17)-(18)):

    * ``D0``: mean distance from each original point to its nearest recovered point, over
      the N1 original points whose nearest recovered point is closer than ``d_theta``.
    * ``dual``: the same from the recovered side, over N2 recovered points.
    * ``mean``: (D0 + dual) / 2.
    * ``N1``, ``N2``: those counts.

    Args:
      original: (N, 3) float32 or float64.
      recovered: (M, 3) float32 or float64; M = 0 (an empty recovery) is allowed.
      d_theta: distance threshold > 0, usually 3 x ``intrinsic_resolution(original)``.

    Returns:
      dict with float ``D0``, ``dual``, ``mean`` and int ``N1``, ``N2``. A direction with no
      pair closer than ``d_theta`` reports the distance ``d_theta`` (never NaN or inf) and a
      count of 0.

    Raises:
      TypeError, ValueError: for invalid clouds or d_theta.

    Examples:
      >>> import numpy as np, hgjax
      >>> a = np.array([[0., 0, 0], [1, 0, 0]])
      >>> b = np.array([[0., 0.1, 0], [5, 0, 0]])
      >>> m = hgjax.eval.recovery_metrics(a, b, d_theta=0.5)
      >>> round(m["D0"], 6), round(m["dual"], 6), m["N1"], m["N2"]
      (0.1, 0.1, 1, 1)
    """
    orig = _validate.check_points(original, "original")
    rec = _as_cloud(recovered, "recovered")
    d_theta = _validate.check_positive(d_theta, "d_theta")
    return _summary(_nearest(rec, orig, d_theta), _nearest(orig, rec, d_theta), d_theta)


def _as_cloud(points, name: str) -> np.ndarray:
    """check_points that also accepts an empty (0, 3) cloud."""
    arr = np.asarray(points)
    if arr.ndim == 2 and arr.shape == (0, 3):
        if arr.dtype not in _validate.FLOAT_DTYPES:
            raise TypeError(f"{name} must have dtype float32 or float64; got {arr.dtype}")
        return arr
    return _validate.check_points(arr, name)


def recover(kept_points, original, *, alphas: Sequence[float] | None = None,
            n_samples: int | None = None, seed: int = 0) -> Recovery:
    """Recover a dense cloud from a resampled one (paper section IV-C).

    For each alpha, the boundary of the alpha complex of ``kept_points``
    (:func:`alpha_complex`) is sampled by Poisson-disk sampling
    (``trimesh.sample.sample_surface_even``: 3 x ``n_samples`` random surface points, thinned
    so that no two are closer than sqrt(area / (3 n_samples))). The recovery with the most
    original points closer than d_theta = 3 x ``intrinsic_resolution(original)`` (N1) is
    kept; ties go to the smaller D0 (:func:`recovery_metrics`), then to the smaller alpha.

    Args:
      kept_points: (M, 3) float32 or float64, the resampled cloud (``points[idx]``).
      original: (N, 3) float32 or float64, the cloud it was resampled from. Only used to
        set the alpha scale and d_theta and to pick the best alpha; it is not sampled.
      alphas: the alpha values to try, lengths > 0. Default: :data:`ALPHA_FACTORS` (4, 8,
        16, 32, 64, 128) x the intrinsic resolution of ``original``: a doubling scale from
        about the kept points' spacing at ratio 0.2 (two or three times the original's) to
        the convex hull of a cloud of a few thousand points. Measured on 14 meshes (882 runs
        of bench/recovery_table.py, 9 methods, ratios 0.05-0.5), the chosen factor was 4 x
        in 14 %, 8 x in 49 %, 16 x in 20 % and 32-128 x in 17 % of runs.
      n_samples: target number of recovered points (Poisson-disk sampling may return
        fewer). Default: N, the size of ``original``.
      seed: seed of the surface sampler, so recoveries are reproducible.

    Returns:
      A :class:`Recovery`; empty (``points`` of shape (0, 3), ``alpha = 0.0``) with a
      status that says why when no alpha gives a surface.

    Raises:
      TypeError, ValueError: for invalid clouds, alphas, n_samples or seed.

    Examples:
      >>> import numpy as np, trimesh, hgjax
      >>> original = trimesh.creation.icosphere(3).sample(2000, seed=0)
      >>> kept = original[hgjax.resample(original, 0.2, method="hkc")]
      >>> rec = hgjax.eval.recover(kept, original)
      >>> rec.status, rec.points.shape[1], rec.n_within > 1900
      ('ok', 3, True)
    """
    kept = _validate.check_points(kept_points, "kept_points")
    orig = _validate.check_points(original, "original")
    _validate.check_min_points(orig.shape[0], 2, "an intrinsic resolution", "original")
    resolution = intrinsic_resolution(orig)
    if alphas is None:
        alphas = [f * resolution for f in ALPHA_FACTORS]
    alphas = [_validate.check_positive(a, "alphas") for a in alphas]
    if not alphas:
        raise ValueError("alphas must hold at least one value; got an empty sequence")
    n_samples = _validate.check_int(orig.shape[0] if n_samples is None else n_samples,
                                    "n_samples", minimum=1)
    seed = _validate.check_int(seed, "seed", minimum=0)
    d_theta = D_THETA_FACTOR * resolution

    empty = np.empty((0, 3), kept.dtype)
    simplices, radii, status = _delaunay(kept)
    best, best_rank = None, None
    for alpha in alphas:
        faces = _boundary(kept, simplices[radii < alpha])
        if faces.shape[0] == 0:
            continue
        mesh = trimesh.Trimesh(vertices=kept, faces=faces, process=False)
        points, _ = trimesh.sample.sample_surface_even(mesh, n_samples, seed=seed)
        metrics = _summary(_nearest(points, orig, d_theta), np.zeros(0), d_theta)
        rank = (-metrics["N1"], metrics["D0"], alpha)
        if best_rank is None or rank < best_rank:
            best_rank = rank
            best = Recovery(points.astype(kept.dtype), kept, faces, alpha, metrics["N1"], "ok")
    if best is None:
        return Recovery(empty, kept, np.empty((0, 3), np.int64), 0.0, 0,
                        "empty" if status == "ok" else status)
    return best
