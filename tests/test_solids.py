"""hgjax.eval.solids: the meshed solids' sharp-edge labels, sampling regimes and noise."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from hgjax.eval import solids


@pytest.mark.parametrize("family", solids.FAMILIES)
def test_every_family_is_closed_and_deterministic(family):
    a, b = solids.random_solid(4, family), solids.random_solid(4, family)
    assert a.is_watertight
    np.testing.assert_array_equal(a.vertices, b.vertices)
    smooth = family in ("sphere", "filleted")
    assert (a.face_adjacency_angles.max() < solids.AMBIGUOUS_ANGLE) == smooth


def test_chamfers_crease_at_45_degrees_and_corners_at_35():
    creases = solids.random_solid(2, "chamfered").face_adjacency_angles
    creases = np.unique(np.round(np.rad2deg(creases[creases > 1e-6]), 6))
    np.testing.assert_allclose(creases, [np.rad2deg(np.arccos(np.sqrt(2 / 3))), 45.0], atol=1e-6)


@pytest.mark.parametrize("regime", solids.MESH_REGIMES)
def test_box_labels_are_the_band_around_its_twelve_edges(regime):
    cloud = solids.mesh_cloud(trimesh.creation.box((1.0, 1.0, 1.0)), n_points=3000, seed=1, regime=regime,
                              rotate=False)
    p, h = cloud.points, cloud.resolution
    # distance to the nearest of the 12 edges of the unit cube centred at the origin
    d = np.sort(np.abs(np.abs(p) - 0.5), axis=1)[:, :2]
    np.testing.assert_array_equal(cloud.edge_mask, np.linalg.norm(d, axis=1) <= (1.0 if regime == "grid" else 0.9) * h
                                  + 1e-12)
    assert np.abs(np.abs(p).max(axis=1) - 0.5).max() < 1e-12  # on the surface
    if regime == "grid":  # a lattice of spacing sqrt(area / N) on each face, no duplicates
        from scipy.spatial import cKDTree

        nearest = cKDTree(p).query(p, k=2)[0][:, 1]
        assert nearest.min() > 0.5 * h and np.median(nearest) == pytest.approx(np.sqrt(6 / 3000))


def test_varying_density_is_several_times_denser_on_one_side():
    mesh = trimesh.creation.box((1.0, 1.0, 1.0))
    cloud = solids.mesh_cloud(mesh, n_points=6000, seed=2, regime="varying", rotate=False)
    again = solids.mesh_cloud(mesh, n_points=6000, seed=2, regime="varying", rotate=False)
    np.testing.assert_array_equal(cloud.points, again.points)
    assert len(np.unique(cloud.points, axis=0)) == 6000
    shift = cloud.points.mean(axis=0)  # uniform points on the box centred at 0 average about 0
    direction = shift / np.linalg.norm(shift)
    along = cloud.points @ direction
    assert (along > 0).sum() > 1.5 * (along < 0).sum()  # 2.8 times as many on the dense half along the change
    uniform = solids.mesh_cloud(mesh, n_points=6000, seed=2, rotate=False).points @ direction
    assert 0.9 < (uniform > 0).sum() / (uniform < 0).sum() < 1.1


def test_even_regime_is_blue_noise():
    from scipy.spatial import cKDTree

    mesh = trimesh.creation.box((1.0, 1.0, 1.0))
    clouds = {regime: solids.mesh_cloud(mesh, n_points=4000, seed=4, regime=regime, rotate=False).points
              for regime in ("even", "random")}
    again = solids.mesh_cloud(mesh, n_points=4000, seed=4, regime="even", rotate=False).points
    np.testing.assert_array_equal(clouds["even"], again)
    assert 3000 < len(again) <= 4000
    spread = {}
    for regime, p in clouds.items():
        nearest = cKDTree(p).query(p, k=2)[0][:, 1]
        spread[regime] = np.percentile(nearest, [5, 95]) / np.median(nearest)
    assert 0.7 < spread["even"][0] and spread["even"][1] < 1.6  # about 0.85 and 1.38
    assert spread["random"][0] < 0.4 and spread["random"][1] > 1.8  # i.i.d.: about 0.28 and 2.0


def test_normal_noise_moves_points_along_the_faces_normals_only():
    mesh = trimesh.creation.box((1.0, 1.0, 1.0))
    clean = solids.mesh_cloud(mesh, n_points=2000, seed=3, rotate=False)
    noisy = solids.mesh_cloud(mesh, n_points=2000, seed=3, rotate=False, noise=0.5, noise_kind="normal")
    move = noisy.points - clean.points
    assert (np.count_nonzero(np.abs(move) > 1e-12, axis=1) == 1).all()  # one axis: the face's normal
    assert 0.3 < np.std(move[np.abs(move) > 0]) / clean.resolution < 0.7
    np.testing.assert_array_equal(noisy.edge_mask, clean.edge_mask)


def test_arguments_are_checked():
    with pytest.raises(ValueError, match="family"):
        solids.random_solid(0, "torus")
    with pytest.raises(ValueError, match="noise_kind"):
        solids.solid_cloud(seed=0, family="sphere", n_points=100, noise_kind="radial")
    with pytest.raises(ValueError, match="noise"):
        solids.solid_cloud(seed=0, family="sphere", n_points=100, noise=-1.0)
