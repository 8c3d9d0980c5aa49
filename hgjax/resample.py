"""The method registry and :func:`resample`, the thin composition score -> select."""

from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np

from hgjax import _validate, samplers, scores
from hgjax.select import top_k, weighted_sample

__all__ = ["METHODS", "Method", "resample"]


@dataclasses.dataclass(frozen=True)
class Method:
    """A registered resampling method.

    Attributes:
      name: registry key.
      run: ``run(points, ratio, *, key, **params) -> indices (M,)`` on validated points.
      summary: one line for the README and ``--help``.
      citation: where the method comes from.

    Examples:
      >>> import hgjax
      >>> hgjax.METHODS["hkc"].citation
      'Deng, Zhang, Ding, IEEE TIP 31, 2022, Alg. 1, Eq. (11)'
    """

    name: str
    run: Callable[..., np.ndarray]
    summary: str
    citation: str


def _by_score(score: Callable, *, largest: bool, wants_ratio: bool = False) -> Callable:
    def run(points, ratio, *, key=None, **params):
        del key  # deterministic
        if wants_ratio:
            params["ratio"] = ratio
        values = score(points, **params)
        return top_k(values, _validate.n_keep(points.shape[0], ratio), largest=largest)

    return run


GFR_MODES = ("random", "top")


def _gfr(points, ratio, *, key=None, mode="random", **params):
    """GFR selection: weighted sampling with pi = 0.8 score / sum + 0.2 / N, or the top scores."""
    mode = _validate.check_choice(mode, "mode", GFR_MODES)
    if mode == "random":
        samplers.check_key(key, "gfr", ' (or mode="top" for the deterministic top scores)')
    values = scores.gfr(points, **params)
    n, m = values.shape[0], _validate.n_keep(points.shape[0], ratio)
    if mode == "top":
        return top_k(values, m, largest=True)
    total = float(np.sum(values, dtype=np.float64))
    pi = 0.8 * values.astype(np.float64) / total + 0.2 / n if total > 0 else np.full(n, 1.0 / n)
    return weighted_sample(key, pi, m)


def _pca_ac(points, ratio, *, key=None, **params):
    """Highest cluster numbers first, then the largest variation, then the lowest index."""
    del key  # deterministic
    labels, variation = scores.pca_ac(points, **params)
    order = np.lexsort((np.arange(labels.shape[0]), -variation, -labels))
    return order[: _validate.n_keep(points.shape[0], ratio)].astype(np.int64)


def _sampler(fn: Callable, *, takes_key: bool = False) -> Callable:
    """Adapt a sampler ``fn(points, ratio, [key=], **params)`` to the ``Method.run`` signature."""

    def run(points, ratio, *, key=None, **params):
        return fn(points, ratio, key=key, **params) if takes_key else fn(points, ratio, **params)

    return run


PAPER = "Deng, Zhang, Ding, IEEE TIP 31, 2022"
DICTA = "Bazazian, Casas, Ruiz-Hidalgo, DICTA 2015"

METHODS: dict[str, Method] = {
    "hkc": Method("hkc", _by_score(scores.hkc, largest=False),
                  "hypergraph kernel convolution: keep the smallest high/low band ratio beta",
                  f"{PAPER}, Alg. 1, Eq. (11)"),
    "hkf": Method("hkf", _by_score(scores.hkf, largest=False),
                  "hypergraph kernel filtering: keep the smallest high-band share sigma",
                  f"{PAPER}, Alg. 2, Eq. (12)"),
    "lhf": Method("lhf", _by_score(scores.lhf, largest=True, wants_ratio=True),
                  "local hypergraph filtering: keep the largest two-length sharpness gamma",
                  f"{PAPER}, Alg. 3, Eqs. (14)-(16)"),
    "gfr": Method("gfr", _gfr,
                  "graph filtering baseline: sample by the graph high-pass ||(L P)_i|| (needs key,"
                  ' or mode="top")', "Chen, Tian, Feng, Vetro, Kovacevic, IEEE TSP 66(3), 2018"),
    "ea": Method("ea", _by_score(scores.ea, largest=True),
                 "eigenvalue analysis baseline: keep the largest surface variation l0 / (l0 + l1 + l2)",
                 DICTA),
    "pca_ac": Method("pca_ac", _pca_ac,
                     "PCA + agglomerative clustering baseline: Ward clusters of the surface variation,"
                     " sharpest clusters first", DICTA),
    "uniform": Method("uniform", _sampler(samplers.uniform_sample, takes_key=True),
                      "uniformly random subset (needs key)", "random down-sampling"),
    "voxel": Method("voxel", _sampler(samplers.voxel_sample),
                    "one point per voxel of a grid sized by bisection to reach the count",
                    "voxel-grid down-sampling"),
    "fps": Method("fps", _sampler(samplers.farthest_point_sample),
                  "farthest point sampling from point 0", "Eldar, Lindenbaum, Porat, Zeevi, IEEE TIP 6(9), 1997"),
}


def resample(points, ratio: float, *, method: str = "hkc", key=None, **params) -> np.ndarray:
    """Indices of the ceil(ratio * N) points that a method keeps.

    Args:
      points: (N, 3) float32 or float64 (NumPy or JAX array); never modified.
      ratio: fraction alpha of points to keep, in (0, 1].
      method: a key of :data:`hgjax.METHODS` (default ``"hkc"``).
      key: ``jax.random`` key for methods that draw random numbers (ignored by the others).
      **params: keyword parameters of the method's score (e.g. ``variant``, ``lengths``).

    Returns:
      (M,) int64 unique indices into ``points``, M = ceil(ratio N), from the highest to the
      lowest keep priority (ties broken by index), so ``points[idx]`` is the resampled cloud.

    Raises:
      TypeError, ValueError: invalid points, ratio, method or parameters.

    Examples:
      >>> import numpy as np, hgjax
      >>> pts = hgjax.eval.box_union_cloud(seed=0, n_points=2000).points
      >>> idx = hgjax.resample(pts, 0.2, method="hkc")
      >>> idx.shape, len(set(idx.tolist()))
      ((400,), 400)
    """
    pts = _validate.check_points(points)
    ratio = _validate.check_ratio(ratio)
    spec = METHODS[_validate.check_choice(method, "method", METHODS)]
    return spec.run(pts, ratio, key=key, **params)
