"""Dense recovery (paper section IV-C): alpha complex, recover, recovery metrics, bench run."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest
import trimesh

import hgjax
from fixtures import sphere
from hgjax.eval import ALPHA_FACTORS, Recovery, alpha_complex, recover, recovery_metrics

ROOT = Path(__file__).resolve().parents[1]


def naive_metrics(original, recovered, d_theta):
    """All-pairs reference of recovery_metrics (paper Eqs. (17)-(18))."""
    dist = np.linalg.norm(original[:, None, :] - recovered[None, :, :], axis=-1)
    d_o, d_r = dist.min(axis=1), dist.min(axis=0)
    n1, n2 = d_o < d_theta, d_r < d_theta
    d0 = d_o[n1].mean() if n1.any() else d_theta
    dual = d_r[n2].mean() if n2.any() else d_theta
    return {"D0": d0, "dual": dual, "mean": (d0 + dual) / 2, "N1": int(n1.sum()), "N2": int(n2.sum())}


# --- alpha complex -----------------------------------------------------------------------


def test_alpha_complex_of_a_dense_sphere_is_a_closed_outward_surface():
    pts = sphere(1500, seed=0)
    faces = alpha_complex(pts, 1.5)  # every Delaunay tetrahedron of cospherical points has R = 1
    mesh = trimesh.Trimesh(pts, faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume == pytest.approx(4 / 3 * np.pi, rel=0.02)  # positive: normals point out
    centres = np.linalg.norm(mesh.triangles_center, axis=1)
    assert centres.min() > 0.98 and centres.max() <= 1.0


def test_alpha_complex_of_a_cube_shell_keeps_its_boundary():
    # Points on the surface of a unit cube: the complex at a large alpha is the cube's hull.
    box = trimesh.creation.box()
    pts, _ = trimesh.sample.sample_surface(box, 1200, seed=1)
    mesh = trimesh.Trimesh(pts, alpha_complex(pts, 2.0), process=False)
    assert mesh.is_watertight
    assert mesh.volume == pytest.approx(1.0, rel=0.02)
    # A single tetrahedron: its circumradius sqrt(3)/2 decides everything.
    corners = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    assert alpha_complex(corners, 0.87).shape == (4, 3)
    assert alpha_complex(corners, 0.86).shape == (0, 3)


def test_alpha_complex_drops_triangles_shared_by_two_kept_tetrahedra():
    # Two tetrahedra glued on the triangle (0, 1, 2): 7 faces, 6 on the boundary.
    pts = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0.3, 0.3, 0.8], [0.3, 0.3, -0.8]])
    faces = alpha_complex(pts, 10.0)
    assert faces.shape == (6, 3)
    assert sorted(map(tuple, np.sort(faces, axis=1))).count((0, 1, 2)) == 0
    assert trimesh.Trimesh(pts, faces, process=False).volume > 0


# --- recover -----------------------------------------------------------------------------


def test_recover_sphere_from_a_fifth_of_its_points():
    original = sphere(3000, seed=2)
    kept = original[np.random.default_rng(3).choice(3000, 600, replace=False)]
    rec = recover(kept, original, seed=0)
    assert isinstance(rec, Recovery) and rec.status == "ok"
    assert rec.mesh.is_watertight
    radii = np.linalg.norm(rec.points, axis=1)
    assert np.abs(radii - 1).max() < 0.04 and np.abs(radii - 1).mean() < 0.01  # chord sag
    assert 2700 <= rec.points.shape[0] <= 3000
    res = hgjax.intrinsic_resolution(original)
    assert rec.alpha in [f * res for f in ALPHA_FACTORS] and rec.alpha >= 1.0
    m = recovery_metrics(original, rec.points, d_theta=3 * res)
    assert m["N1"] == rec.n_within == 3000
    assert m["D0"] < res


def test_recover_picks_the_alpha_with_most_original_points_within_d_theta():
    original = sphere(2000, seed=4)
    kept = original[::5]
    res = hgjax.intrinsic_resolution(original)
    alphas = [0.5, 1.5, 3.0]  # 0.5: no tetrahedron (all have R = 1); 1.5 and 3.0: the hull
    rec = recover(kept, original, alphas=alphas, seed=1)
    assert rec.alpha == 1.5  # ties on N1 and D0 go to the smaller alpha
    alone = recover(kept, original, alphas=[3.0], seed=1)
    np.testing.assert_array_equal(rec.points, alone.points)
    assert rec.n_within == recovery_metrics(original, rec.points, d_theta=3 * res)["N1"]


def test_recover_keeps_dtype_and_does_not_modify_inputs(dtype):
    original = sphere(1000, seed=5).astype(dtype)
    kept = original[::4].copy()
    before = (original.copy(), kept.copy())
    rec = recover(kept, original, n_samples=500, seed=0)
    assert rec.points.dtype == dtype and rec.points.shape[0] <= 500
    np.testing.assert_array_equal(original, before[0])
    np.testing.assert_array_equal(kept, before[1])


def test_recover_is_reproducible_with_its_seed():
    original = sphere(1000, seed=6)
    a = recover(original[::5], original, seed=3)
    b = recover(original[::5], original, seed=3)
    c = recover(original[::5], original, seed=4)
    np.testing.assert_array_equal(a.points, b.points)
    assert not np.array_equal(a.points, c.points)


# --- degenerate cases --------------------------------------------------------------------


def _assert_empty(rec, status, original):
    assert rec.status == status
    assert rec.points.shape == (0, 3) and rec.faces.shape == (0, 3)
    assert rec.alpha == 0.0 and rec.n_within == 0
    m = recovery_metrics(original, rec.points, d_theta=0.1)
    assert m == {"D0": 0.1, "dual": 0.1, "mean": 0.1, "N1": 0, "N2": 0}


def test_fewer_than_four_kept_points_give_an_empty_recovery():
    original = sphere(500, seed=7)
    _assert_empty(recover(original[:3], original), "too_few_points", original)
    assert alpha_complex(original[:3], 1.0).shape == (0, 3)


@pytest.mark.parametrize("flat", ["coplanar", "collinear", "duplicates"])
def test_flat_kept_points_give_an_empty_recovery(flat):
    rng = np.random.default_rng(8)
    original = sphere(500, seed=8)
    kept = {"coplanar": np.c_[rng.normal(size=(50, 2)), np.zeros(50)],
            "collinear": np.outer(rng.normal(size=20), [1.0, 2.0, 3.0]),
            "duplicates": np.ones((10, 3))}[flat]
    _assert_empty(recover(kept, original), "flat", original)
    assert alpha_complex(kept, 1.0).shape == (0, 3)


def test_an_alpha_without_tetrahedra_gives_no_triangles():
    original = sphere(800, seed=9)
    assert alpha_complex(original, 0.5).shape == (0, 3)
    _assert_empty(recover(original[::4], original, alphas=[0.2, 0.5]), "empty", original)


def test_recover_rejects_bad_arguments():
    original = sphere(200, seed=10)
    with pytest.raises(ValueError, match="alphas"):
        recover(original, original, alphas=[1.0, -1.0])
    with pytest.raises(ValueError, match="alphas"):
        recover(original, original, alphas=[])
    with pytest.raises(ValueError, match="n_samples"):
        recover(original, original, n_samples=0)
    with pytest.raises(ValueError, match="original"):
        recover(original, original[:1])
    with pytest.raises(TypeError, match="kept_points"):
        recover(original.astype(np.int64), original)
    with pytest.raises(ValueError, match="alpha"):
        alpha_complex(original, 0.0)


# --- metrics -----------------------------------------------------------------------------


def test_metrics_of_identical_clouds_are_zero():
    pts = sphere(400, seed=11)
    assert recovery_metrics(pts, pts, d_theta=0.05) == {"D0": 0.0, "dual": 0.0, "mean": 0.0,
                                                        "N1": 400, "N2": 400}


def test_metrics_match_hand_computed_values_on_a_toy_pair():
    original = np.array([[0.0, 0, 0], [1, 0, 0], [0, 2, 0]])
    recovered = np.array([[0.0, 0.125, 0], [1, 0.25, 0], [1, 0.375, 0], [1, 0.5, 1]])
    m = recovery_metrics(original, recovered, d_theta=0.5)
    # original -> recovered: 0.125, 0.25, and (0, 2, 0) has nothing within 0.5.
    # recovered -> original: 0.125, 0.25, 0.375; (1, 0.5, 1) is farther than 0.5.
    assert m["D0"] == pytest.approx(0.1875) and m["N1"] == 2
    assert m["dual"] == pytest.approx(0.25) and m["N2"] == 3
    assert m["mean"] == pytest.approx(0.21875)
    # The threshold is strict: a pair exactly d_theta apart is not counted.
    assert recovery_metrics(original[:1], np.array([[0.5, 0, 0]]), d_theta=0.5)["N1"] == 0


def test_metrics_match_the_all_pairs_reference():
    rng = np.random.default_rng(12)
    original, recovered = rng.random((300, 3)), rng.random((250, 3))
    got = recovery_metrics(original, recovered, d_theta=0.08)
    want = naive_metrics(original, recovered, 0.08)
    assert got["N1"] == want["N1"] and got["N2"] == want["N2"] and 0 < got["N1"] < 300
    for key in ("D0", "dual", "mean"):
        assert got[key] == pytest.approx(want[key], rel=1e-12)


def test_metrics_validate_their_arguments():
    pts = sphere(10, seed=13)
    with pytest.raises(ValueError, match="d_theta"):
        recovery_metrics(pts, pts, d_theta=-1.0)
    with pytest.raises(ValueError, match="recovered"):
        recovery_metrics(pts, pts[:, :2], d_theta=1.0)
    with pytest.raises(TypeError, match="original"):
        recovery_metrics(pts.astype(int), pts, d_theta=1.0)


# --- the bench, end to end ---------------------------------------------------------------


def test_recovery_bench_quick_run(tmp_path):
    spec = importlib.util.spec_from_file_location("recovery_table", ROOT / "bench" / "recovery_table.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    rows = bench.main(["--quick", "--methods", "hkc", "--out", str(tmp_path)])
    names = {p.name for p in tmp_path.iterdir()}
    assert {"recovery_table.md", "recovery_runs.csv", "recovery_curves.png",
            "recovery_fandisk.png", "recovery_laptop_kenney.png"} <= names
    assert len(rows) == 2 * 2  # two meshes x two ratios x one seed
    assert all(r["status"] == "ok" and r["N1"] > 0.8 * r["n_points"] for r in rows)
    assert all(0 < r["D0"] < 0.05 for r in rows)  # unit-diagonal shapes, 600 points
    text = (tmp_path / "recovery_table.md").read_text()
    assert "python bench/recovery_table.py --quick --methods hkc" in text and "**" in text
