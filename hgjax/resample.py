"""The method registry and :func:`resample`, the thin composition score -> select."""

from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np

from hgjax import _validate, scores
from hgjax.select import top_k

__all__ = ["METHODS", "Method", "resample"]


@dataclasses.dataclass(frozen=True)
class Method:
    """A registered resampling method.

    Attributes:
      name: registry key.
      run: ``run(points, ratio, *, key, **params) -> indices (M,)`` on validated points.
      summary: one line for the README and ``--help``.
      citation: where the method comes from.
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


PAPER = "Deng, Zhang, Ding, IEEE TIP 31, 2022"

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
