"""hgjax.eval grid regime: lattice points on the outer surface of box unions, exact labels."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

import hgjax
from hgjax.eval import synthetic

CUBE = np.array([[[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]])
# An L-shaped prism: a 2 x 1 x 1 box and a unit cube on its y = 1 side, sharing the square
# x in [0, 1], z in [0, 1]; the union has a concave edge along z at x = 1, y = 1.
ELL = np.array([[[0.0, 0.0, 0.0], [2.0, 1.0, 1.0]], [[0.0, 1.0, 0.0], [1.0, 2.0, 1.0]]])
# The L's 18 sharp edges by hand: its cross-section polygon at z = 0 and z = 1, and the
# six vertical edges at the polygon's corners (five convex, one concave at (1, 1)).
ELL_CORNERS = [(0, 0), (2, 0), (2, 1), (1, 1), (1, 2), (0, 2)]
TOWER = np.array([[[0.0, 0.0, 0.0], [4.0, 4.0, 2.0]], [[1.0, 1.0, 2.0], [3.0, 3.0, 4.0]]])


def _ell_edges():
    edges = []
    for (x0, y0), (x1, y1) in zip(ELL_CORNERS, ELL_CORNERS[1:] + ELL_CORNERS[:1]):
        edges += [((x0, y0, z), (x1, y1, z)) for z in (0.0, 1.0)]
    edges += [((x, y, 0.0), (x, y, 1.0)) for x, y in ELL_CORNERS]
    return np.array(edges, dtype=float)


def _naive_distance(p, edges):
    """Distance to the nearest segment, one segment at a time."""
    best = np.full(len(p), np.inf)
    for a, b in edges:
        t = np.clip((p - a) @ (b - a) / ((b - a) @ (b - a)), 0, 1)
        best = np.minimum(best, np.linalg.norm(p - a - t[:, None] * (b - a), axis=1))
    return best


def _box_count(nx, ny, nz):
    """Lattice points on the surface of an nx x ny x nz (in steps) box: all minus the interior ones."""
    return (nx + 1) * (ny + 1) * (nz + 1) - (nx - 1) * (ny - 1) * (nz - 1)


@pytest.mark.parametrize("m", [4, 6, 9])
def test_cube_counts_by_hand(m):
    cloud = synthetic.grid_box_union(CUBE, subdivisions=m, seed=0)
    # 6 faces of (m + 1)^2 points; the 12 edges of m - 1 inner points are on 2 faces, the 8 corners on 3.
    assert len(cloud.points) == 6 * (m + 1) ** 2 - 12 * (m - 1) - 2 * 8 == 6 * m**2 + 2
    # Not an edge point: 2 or more steps from every edge, i.e. both face coordinates in [2, m - 2].
    assert int(cloud.edge_mask.sum()) == 6 * m**2 + 2 - 6 * (m - 3) ** 2
    assert cloud.resolution == 1 / m and cloud.delta == 1 / m
    lattice = np.rint(cloud.points * m)
    np.testing.assert_allclose(cloud.points * m, lattice, rtol=0, atol=1e-12)
    # On a face (one coordinate 0 or m), an edge point has a second coordinate within one step of 0 or m.
    near = ((lattice <= 1) | (lattice >= m - 1)).sum(axis=1)
    np.testing.assert_array_equal(cloud.edge_mask, near >= 2)


def test_ell_counts_labels_and_concave_edge():
    n = 4
    cloud = synthetic.grid_box_union(ELL, subdivisions=n, seed=3)
    q = np.rint(cloud.points * n).astype(int)
    # Both boxes' surface points, less the shared square: its (n - 1)^2 inner points are inside the
    # union (dropped from both boxes) and its 4 n boundary points are on both boxes' surfaces.
    assert len(q) == _box_count(2 * n, n, n) + _box_count(n, n, n) - 2 * (n - 1) ** 2 - 4 * n == 226
    np.testing.assert_array_equal(cloud.edge_mask, _naive_distance(cloud.points, _ell_edges()) <= 1 / n + 1e-12)
    present = {tuple(r) for r in q}
    label = dict(zip(map(tuple, q), cloud.edge_mask))
    # Concave edge (4, 4, k): on it, one step from it on either face, but not two steps away.
    for k in range(n + 1):
        assert label[4, 4, k] and label[5, 4, k] and label[4, 5, k]
    assert not label[6, 4, 2] and not label[4, 6, 2]
    # The shared square y = 1, 0 < x < 1, 0 < z < 1 is inside the union: no point there.
    assert not any((x, 4, z) in present for x in range(1, n) for z in range(1, n))
    # The empty quadrant x > 1, y > 1 carries nothing.
    assert not ((q[:, 0] > 4) & (q[:, 1] > 4)).any()


def test_no_duplicates_and_outer_surface_only():
    for boxes in [TOWER] + [synthetic.random_boxes(s) for s in range(1, 6)]:
        n = 3
        cloud = synthetic.grid_box_union(boxes, subdivisions=n, seed=1)
        q = np.rint(cloud.points * n).astype(int)
        assert np.unique(q, axis=0).shape[0] == len(q)
        # On some box face, strictly inside no box.
        lo, hi = (boxes * n)[:, 0][None], (boxes * n)[:, 1][None]
        inside = ((q[:, None] > lo) & (q[:, None] < hi)).all(-1).any(-1)
        closed = ((q[:, None] >= lo) & (q[:, None] <= hi)).all(-1).any(-1)
        assert closed.all() and not inside.any()
        # Each point has an empty unit cell around it (so it is on the boundary).
        corners = np.array(np.meshgrid(*[(-1, 1)] * 3, indexing="ij")).reshape(3, 8).T
        c = 2 * q[:, None] + corners
        full = ((c[:, :, None] > 2 * lo[:, None]) & (c[:, :, None] < 2 * hi[:, None])).all(-1).any(-1)
        assert not full.all(axis=1).any()
    # The tower's shared patch z = 2 under the upper box carries no point; the base's outer top does.
    p = synthetic.grid_box_union(TOWER, subdivisions=2, seed=0).points
    on_top = np.isclose(p[:, 2], 2.0)
    assert not (on_top & (p[:, :2] > 1).all(1) & (p[:, :2] < 3).all(1)).any()
    assert (on_top & (p[:, 0] < 1)).any()


def test_deterministic_and_seeded():
    a = synthetic.grid_box_union(TOWER, subdivisions=3, seed=5, rotate=True, noise=0.2)
    b = synthetic.grid_box_union(TOWER, subdivisions=3, seed=5, rotate=True, noise=0.2)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    c = synthetic.grid_box_union(TOWER, subdivisions=3, seed=6)
    clean = synthetic.grid_box_union(TOWER, subdivisions=3, seed=5)
    assert not np.array_equal(c.points, clean.points)  # another row order
    sort = lambda p: p[np.lexsort(p.T)]  # noqa: E731
    np.testing.assert_array_equal(sort(c.points), sort(clean.points))


def test_noise_rotation_and_labels():
    clean = synthetic.grid_box_union(TOWER, subdivisions=6, seed=2)
    noisy = synthetic.grid_box_union(TOWER, subdivisions=6, seed=2, noise=0.1)
    np.testing.assert_array_equal(clean.edge_mask, noisy.edge_mask)
    assert np.std(noisy.points - clean.points) == pytest.approx(0.1 / 6, rel=0.05)
    rotated = synthetic.grid_box_union(TOWER, subdivisions=6, seed=2, rotate=True)
    np.testing.assert_allclose(np.linalg.norm(rotated.points - rotated.points[0], axis=1),
                               np.linalg.norm(clean.points - clean.points[0], axis=1), atol=1e-12)
    assert clean.resolution == pytest.approx(hgjax.intrinsic_resolution(clean.points))


def test_edge_points_on_the_sharp_edges():
    cloud = synthetic.grid_box_union(ELL, subdivisions=4, seed=0)
    assert _naive_distance(cloud.edge_points, _ell_edges()).max() < 1e-12
    # ... and they cover every hand-listed edge, at most EDGE_SPACING resolutions apart.
    t = np.linspace(0, 1, 101)[:, None, None]
    along = (_ell_edges()[:, 0] + t * (_ell_edges()[:, 1] - _ell_edges()[:, 0])).reshape(-1, 3)
    gap = cKDTree(cloud.edge_points).query(along)[0].max()
    assert gap <= synthetic.EDGE_SPACING * cloud.resolution / 2 + 1e-12


def test_subdivisions_and_regime_switch():
    # Tower outer area by hand: base 2 * 16 + 4 * 8 = 64, less the covered 2 x 2 patch, plus the
    # upper box's 4 sides of 2 x 2 and its top: 80.
    assert synthetic.grid_subdivisions(TOWER, 80 * 9) == 3
    assert synthetic.grid_subdivisions(CUBE, 1) == 1
    cloud = hgjax.eval.box_union_cloud(seed=2, n_points=5000, regime="grid", noise=0.1)
    assert abs(len(cloud.points) - 5000) < 1000 and cloud.name == "grid-boxes2"
    assert cloud.delta == cloud.resolution * synthetic.GRID_DELTA
    sets = hgjax.eval.synthetic_set(n_shapes=2, n_points=2000, regime="grid")
    assert [c.name for c in sets] == ["grid-boxes0", "grid-boxes1"]
    with pytest.raises(ValueError, match="regime"):
        hgjax.eval.box_union_cloud(seed=0, regime="poisson")


def test_invalid_and_inputs_untouched():
    boxes = ELL.copy()
    boxes.flags.writeable = False
    synthetic.grid_box_union(boxes, subdivisions=2, seed=0)
    np.testing.assert_array_equal(boxes, ELL)
    with pytest.raises(ValueError, match="multiples"):
        synthetic.grid_box_union(ELL + 0.1, subdivisions=2, seed=0)
    with pytest.raises(ValueError):
        synthetic.grid_box_union(ELL, subdivisions=0, seed=0)
    with pytest.raises(ValueError):
        synthetic.grid_box_union(ELL, subdivisions=2, seed=0, noise=-1.0)
