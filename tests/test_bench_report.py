"""bench/_report.SearchLog: a method's own neighbour search, recorded from one call and replayed alone."""

import pathlib
import sys

import numpy as np

import hgjax
from hgjax.neighbours import kdtree

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

import _report  # noqa: E402


def test_search_log_records_every_tree_and_query_and_replays_them():
    points = hgjax.eval.box_surface(3000, seed=0)
    original = (kdtree.Tree.__init__, kdtree.Tree.query)
    built = hgjax.neighbours.spatial.SpatialIndex(points)  # a tree built before the log: recorded from its first query
    built.tree
    log = _report.SearchLog()
    with log:
        kept = hgjax.resample(points, 0.2, method="ea")
        built.tree.query(points[:5], 3)
    assert (kdtree.Tree.__init__, kdtree.Tree.query) == original  # unpatched on exit
    np.testing.assert_array_equal(kept, hgjax.resample(points, 0.2, method="ea"))  # the call's result untouched
    assert len(log.trees) == 2
    (tree_points, queries), (before, late) = log.trees
    assert tree_points.shape == (3000, 3) and before is built.tree.points
    assert [(x.shape, k) for x, k, _, _ in late] == [((5, 3), 3)]
    # the resample asks EA's k + 1 = 17 nearest points of every point once, in its batches
    assert sum(x.shape[0] for x, k, _, _ in queries if k == 17) >= 3000
    assert log.queries == len(queries) + 1
    assert log.seconds() > 0
