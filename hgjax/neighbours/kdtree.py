"""The host k-d tree: the fastest installed engine for each query hgjax makes.

Every neighbourhood hgjax builds on the host comes from :meth:`Tree.query`: the k nearest points of
each query point, optionally only those nearer than a bound. Two engines answer it with the same
distances and the same sets, each where it is fastest (``bench/results/search_engines.md``, 1e6
Morton-sorted float64 box surface, tree build included, / the cKDTree kNN16 floor):

* ``"pykdtree"`` (the ``kdtree`` extra; OpenMP over the query points), where installed: the
  unbounded k-nearest queries (kNN16 0.60 against cKDTree's 0.97, kNN33 1.10 / 1.63, kNN64
  3.06 / 3.35).
* ``"scipy"``: ``scipy.spatial.cKDTree`` with ``workers=-1``: the queries bounded by a distance
  (GFR's k = 109: 3.25 against pykdtree's 6.39; a 64-point ball 2.00 / 2.54), the Chebyshev
  (``p=inf``) cubes, which pykdtree does not offer, and every query where pykdtree is absent.

Both compute a float64 distance as ``sqrt((dx*dx + dy*dy) + dz*dz)`` and both keep only points
strictly nearer than the bound, so their distances are bitwise equal (tests/test_kdtree.py). Equal
distances may come in another order: :class:`hgjax.neighbours.spatial.SpatialIndex` orders them by global id
whatever the engine. Missing neighbours are at distance inf with the index n (the tree's size).
"""

from __future__ import annotations

import threading

import numpy as np
from scipy.spatial import cKDTree

try:
    from pykdtree.kdtree import KDTree as _PyKDTree
except ImportError:  # the kdtree extra is not installed: SciPy answers every query
    _PyKDTree = None

LEAF_SIZE = 16
PREFERRED = ("pykdtree", "scipy")
"""The engines in order of preference; the first one installed answers unbounded Euclidean queries."""


def engine() -> str:
    """The engine of unbounded Euclidean queries: the first of :data:`PREFERRED` that is installed."""
    installed = {"pykdtree": _PyKDTree is not None, "scipy": True}
    return next(name for name in PREFERRED if installed[name])


class Tree:
    """A k-d tree over (n, 3) points: :func:`engine`'s, and cKDTree's for the queries it answers
    (each built on first use; pickled as its points, rebuilt on load by the engine installed there).

    Args:
      points: (n, 3) float array; the tree holds them as float64 (the distances are float64).
    """

    def __init__(self, points: np.ndarray):
        self.points = np.ascontiguousarray(points, dtype=np.float64)
        self.engine = engine()
        self._lock = threading.Lock()
        self._trees = {}
        self._tree(self.engine)  # the other engine's tree is built on its first query

    def _tree(self, name: str):
        """The engine ``name``'s tree over :attr:`points`, built on first use (thread-safe)."""
        with self._lock:
            if name not in self._trees:
                if name == "pykdtree":
                    self._trees[name] = _PyKDTree(self.points, leafsize=LEAF_SIZE)
                else:
                    self._trees[name] = cKDTree(self.points, leafsize=LEAF_SIZE, balanced_tree=False)
            return self._trees[name]

    def __getstate__(self) -> dict:
        return {"points": self.points}

    def __setstate__(self, state: dict) -> None:  # the engine installed where it is loaded
        self.points, self.engine = state["points"], engine()
        self._lock, self._trees = threading.Lock(), {}

    def query(self, x: np.ndarray, k: int, bound: float = np.inf, p: float = 2) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` nearest points of each row of ``x`` (R, 3), nearer than ``bound``, by increasing distance.

        Args:
          x: (R, 3) query points.
          k: neighbours per row, 1 <= k <= n.
          bound: only points at distance < bound (the others: distance inf, index n).
          p: the Minkowski norm, 2 (any engine) or ``np.inf`` (cKDTree).

        Returns:
          (dist, idx): (R, k) float64 distances and (R, k) intp indices into the tree's points.
        """
        x = np.ascontiguousarray(x, dtype=np.float64).reshape(-1, 3)
        if p == 2 and np.isinf(bound) and self.engine == "pykdtree":
            dist, idx = self._tree("pykdtree").query(x, k=k)
        else:
            dist, idx = self._tree("scipy").query(x, k=k, p=p, distance_upper_bound=bound, workers=-1)
        return dist.reshape(x.shape[0], k), idx.reshape(x.shape[0], k).astype(np.intp, copy=False)
