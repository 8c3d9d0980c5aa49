"""Edge-preservation metrics of a resampling (paper Sec. IV-A, Eq. (17)), plus extras.

Precision, recall and F1 of the kept points as edge detectors, the mean distance from kept
points to the nearest ground-truth edge point, the best F1 any method could reach keeping
the same number of points (so F1 / best is comparable across clouds), the average
precision of a ranking (threshold-free) and the Matthews correlation coefficient when as
many points are kept as there are edge points.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from hgjax import _validate
from hgjax.neighbours.spatial import intrinsic_resolution

__all__ = ["average_precision", "edge_metrics", "feature_variation"]


def average_precision(scores, labels) -> float:
    """Average precision of a ranking, higher score = more edge-like (ties grouped).

    AP = sum_n (R_n - R_{n-1}) P_n over the distinct score thresholds, as in scikit-learn's
    ``average_precision_score``: tied scores enter together.

    Args:
      scores: (N,) float scores without NaN.
      labels: (N,) bool, at least one True.

    Returns:
      AP in [0, 1].

    Raises:
      ValueError: mismatched shapes, NaN, or no positive label.

    Examples:
      >>> import numpy as np
      >>> from hgjax.eval import average_precision
      >>> average_precision(np.array([3., 2., 1.]), np.array([True, False, True]))
      0.8333333333333333
    """
    s, y = np.asarray(scores, dtype=np.float64), np.asarray(labels, dtype=bool)
    if s.shape != y.shape or s.ndim != 1:
        raise ValueError(f"scores and labels must both have shape (N,); got {s.shape} and {y.shape}")
    if np.isnan(s).any():
        raise ValueError("scores contains NaN")
    if not y.any():
        raise ValueError("labels has no positive (edge) point")
    order = np.argsort(-s, kind="stable")
    s, y = s[order], y[order]
    last = np.r_[np.flatnonzero(np.diff(s)), s.size - 1]  # end of each group of ties
    tp = np.cumsum(y)[last]
    precision = tp / (last + 1)
    recall_step = np.diff(np.r_[0, tp]) / tp[-1]
    return float(np.sum(recall_step * precision))


def edge_metrics(points, edge_mask, kept, *, scores=None, edge_points=None, resolution=None) -> dict:
    """Edge metrics of the kept points against ground-truth labels.

    Args:
      points: (N, 3) float cloud (the one that was resampled).
      edge_mask: (N,) bool ground truth, E = edge_mask.sum() >= 1.
      kept: (M,) unique int indices of kept points, highest keep priority first (as
        :func:`hgjax.resample` returns them).
      scores: optional (N,) ranking, HIGHER = MORE EDGE-LIKE (negate HKC's beta / HKF's
        sigma first). Without it, the ranking is the kept order: kept[0] ranks first and
        every point not kept ties last.
      edge_points: (E', 3) points on the true edges for the distance (default:
        ``points[edge_mask]``).
      resolution: unit of ``mean_distance_res`` (default: intrinsic resolution of points).

    Returns:
      dict with ``n_kept`` (M), ``n_edge`` (E), ``tp``, ``precision`` (tp / M),
      ``recall`` (tp / E), ``f1`` (= 2 tp / (M + E)), ``best_f1`` (2 min(M, E) / (M + E),
      the best achievable keeping M points), ``f1_over_best`` (= tp / min(M, E)),
      ``mean_distance`` and ``mean_distance_res`` (mean distance from the kept points to
      the nearest edge point, absolute and in resolutions), ``average_precision``, and
      ``mcc`` only when M == E.

    Raises:
      ValueError: mismatched shapes, kept indices out of range or repeated, or no edge.

    Examples:
      >>> import numpy as np
      >>> from hgjax.eval import edge_metrics
      >>> pts = np.arange(15.).reshape(5, 3)
      >>> m = edge_metrics(pts, np.array([1, 1, 0, 0, 0], bool), np.array([0, 2]))
      >>> m["precision"], m["recall"], m["f1"], m["mcc"]
      (0.5, 0.5, 0.5, 0.16666666666666666)
    """
    pts = _validate.check_points(points)
    n = pts.shape[0]
    mask = np.asarray(edge_mask)
    if mask.shape != (n,) or mask.dtype != np.bool_:
        raise ValueError(f"edge_mask must be a bool array of shape ({n},); got {mask.dtype} {mask.shape}")
    e = int(mask.sum())
    if e == 0:
        raise ValueError("edge_mask has no edge point; the metrics are undefined")
    kept = np.asarray(kept)
    if kept.ndim != 1 or kept.size == 0 or not np.issubdtype(kept.dtype, np.integer):
        raise ValueError(f"kept must be a non-empty (M,) integer array; got {kept.dtype} {kept.shape}")
    if kept.min() < 0 or kept.max() >= n or np.unique(kept).size != kept.size:
        raise ValueError(f"kept must hold unique indices in [0, {n}); got min {kept.min()}, max {kept.max()}")
    m = kept.size
    tp = int(mask[kept].sum())
    if scores is None:
        ranking = np.zeros(n)
        ranking[kept] = np.arange(m, 0, -1)
    else:
        ranking = np.asarray(scores, dtype=np.float64)
    ref = pts[mask] if edge_points is None else _validate.check_points(edge_points, "edge_points")
    res = intrinsic_resolution(pts) if resolution is None else _validate.check_positive(resolution, "resolution")
    dist = float(np.mean(cKDTree(ref).query(pts[kept], workers=-1)[0]))
    out = {
        "n_kept": m, "n_edge": e, "tp": tp,
        "precision": tp / m, "recall": tp / e, "f1": 2 * tp / (m + e),
        "best_f1": 2 * min(m, e) / (m + e), "f1_over_best": tp / min(m, e),
        "mean_distance": dist, "mean_distance_res": dist / res if res > 0 else 0.0,
        "average_precision": average_precision(ranking, mask),
    }
    if m == e:
        fp, fn = m - tp, e - tp
        tn = n - tp - fp - fn
        den = np.sqrt(float(tp + fp) * (tp + fn) * (tn + fp) * (tn + fn))
        out["mcc"] = float((tp * tn - fp * fn) / den) if den > 0 else 0.0
    return out


def feature_variation(points: np.ndarray) -> np.ndarray:
    """Surface variation (EA's score) of every point, the colour of ``hgjax compare``.

    Args:
      points: (N, 3) float32 or float64.

    Returns:
      (N,) float64 in [0, 1/3]: 0 on planes, up to 1/3 at corners; all 0 for a cloud of fewer
      points than EA's neighbourhoods hold.

    Examples:
      >>> import numpy as np, hgjax
      >>> flat = np.random.default_rng(0).random((200, 3)) * [1, 1, 0]
      >>> float(hgjax.eval.feature_variation(flat).max()) < 1e-6
      True
    """
    import hgjax

    if len(points) < hgjax.scores.eigen.DEFAULT_K:
        return np.zeros(len(points))
    return np.asarray(hgjax.score(hgjax.neighbourhoods(hgjax.local_frame(points)[0], "ea"), "ea"), np.float64)
