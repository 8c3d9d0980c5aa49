"""The host k-d tree engines (hgjax.neighbours.kdtree): pykdtree where installed, cKDTree otherwise, the same
neighbourhoods. Distances bitwise equal to cKDTree's for every query hgjax makes; every
method keeps the same points with either engine, in one process and in tiles; without pykdtree
SciPy answers."""

import functools

import numpy as np
import pytest
from fixtures import box_union, degenerate_clouds, grid, uniform_cloud
from scipy.spatial import cKDTree

import hgjax
from hgjax.neighbours import kdtree, spatial

pytest.importorskip("pykdtree")


@functools.cache
def _clouds():
    smooth = box_union(1500, seed=3)
    rounded = np.round(smooth * 20) / 20  # many equal distances, and duplicates
    dense = uniform_cloud(300, seed=4, scale=0.05)
    mixed = np.concatenate([box_union(1200, seed=5), dense])  # two densities
    duplicated = np.concatenate([smooth[:600], smooth[:300]])
    return {"smooth": smooth, "rounded": rounded, "mixed": mixed, "duplicated": duplicated,
            "grid": grid((12, 12, 8), 0.1), "float32": smooth.astype(np.float32)}


@pytest.fixture(params=["pykdtree", "scipy"])
def engine(request, monkeypatch):
    """Each engine in turn (scipy: as where pykdtree is not installed)."""
    if request.param == "scipy":
        monkeypatch.setattr(kdtree, "_PyKDTree", None)
    assert kdtree.engine() == request.param
    return request.param


@pytest.mark.full
@pytest.mark.parametrize("name", list(_clouds()))
@pytest.mark.parametrize("k, bound", [(1, np.inf), (16, np.inf), (33, np.inf), (64, np.inf), (64, "ball"), (109, "ball")])
def test_distances_equal_ckdtree_bitwise(name, k, bound, engine):
    """Every Euclidean query's distances are cKDTree's to the bit, the missing ones inf at index n,
    and the indices name points at those distances (equal distances may come in another order)."""
    local = spatial.local_frame(_clouds()[name])[0]
    if bound == "ball":  # about HKC's ball: a few times the nearest spacing
        bound = 2.5 * float(np.median(cKDTree(local).query(local, k=2)[0][:, 1]))
    tree = kdtree.Tree(local)
    assert tree.engine == engine
    dist, idx = tree.query(local, k, bound)
    want = cKDTree(local).query(local, k=k, distance_upper_bound=bound)[0].reshape(len(local), k)
    np.testing.assert_array_equal(dist, want)
    found = np.isfinite(dist)
    assert (idx[~found] == len(local)).all() and (idx[found] < len(local)).all()
    gap = local[np.where(found, idx, 0)] - local[:, None, :]
    np.testing.assert_array_equal(np.where(found, np.sqrt((gap[..., 0] ** 2 + gap[..., 1] ** 2) + gap[..., 2] ** 2),
                                           np.inf), dist)


def test_chebyshev_cubes_answered_by_ckdtree(engine):
    """The cube (p = inf) query, which pykdtree lacks, is cKDTree's whatever the engine."""
    local = spatial.local_frame(_clouds()["rounded"])[0]
    dist, idx = kdtree.Tree(local).query(local, 16, 0.05, p=np.inf)
    want = cKDTree(local, leafsize=16, balanced_tree=False).query(local, k=16, p=np.inf, distance_upper_bound=0.05)
    np.testing.assert_array_equal(dist, want[0])
    np.testing.assert_array_equal(idx, want[1])


def test_tree_pickles_as_its_points(engine):
    """A tree sent to a Dask worker is rebuilt there by the same engine: the same answers."""
    import pickle

    local = spatial.local_frame(_clouds()["smooth"])[0]
    tree = kdtree.Tree(local)
    back = pickle.loads(pickle.dumps(tree))
    assert back.engine == engine
    for got, want in zip(back.query(local[:50], 8), tree.query(local[:50], 8)):
        np.testing.assert_array_equal(got, want)


@pytest.mark.full
@pytest.mark.parametrize("name", ["rounded", "duplicated"])
def test_every_method_keeps_the_same_points_with_either_engine(name, monkeypatch):
    """Kept indices and scores of every scoring method, in one process and in tiles (those that tile),
    are the same
    whether pykdtree or cKDTree answers the queries."""
    import jax

    from hgjax import tiles

    points = _clouds()[name]

    def run():
        out = {}
        for m, method in hgjax.METHODS.items():
            if isinstance(method, hgjax.Method):
                key = {"key": jax.random.key(3)} if method.needs_key else {}
                kept, scores = tiles.resample(points, 0.2, method=m, return_scores=True, **key)
                tiled = () if method.tiling.whole_selection else (tiles.resample(points, 0.2, method=m, tile=0.5, **key),)
                out[m] = (kept, scores, *tiled)
        return out

    fast = run()
    monkeypatch.setattr(kdtree, "_PyKDTree", None)
    for m, want in run().items():
        for got, wanted in zip(fast[m], want):
            np.testing.assert_array_equal(np.asarray(got), np.asarray(wanted), err_msg=m)


@pytest.mark.full
@pytest.mark.parametrize("name", list(degenerate_clouds()))
@pytest.mark.parametrize("k", [1, 5, 16, 39])
def test_knn_of_degenerate_clouds_is_the_naive_order(name, k, engine):
    """Each row is the point itself, then the others by (distance, index), whatever order the tree
    lists equal distances in (two locations of 20 copies each: the point itself may come last)."""
    points = degenerate_clouds()[name]
    local = spatial.local_frame(points)[0]  # the frame hgjax measures distances in
    gap = local[None, :, :] - local[:, None, :]
    dist = np.sqrt((gap[..., 0] ** 2 + gap[..., 1] ** 2) + gap[..., 2] ** 2)
    np.fill_diagonal(dist, -1.0)
    want = np.lexsort((np.broadcast_to(np.arange(len(points)), dist.shape), dist), axis=1)[:, :k]
    np.testing.assert_array_equal(hgjax.knn(points, k).idx, want)
