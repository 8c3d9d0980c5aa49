"""hgjax.eval edge benchmark: exact labels, outer-surface sampling, metrics, the bench script."""

import pathlib
import sys

import numpy as np
import pytest

import hgjax
from hgjax.eval import synthetic

ROOT = pathlib.Path(__file__).resolve().parents[1]
CUBE = np.array([[[0.0, 0.0, 0.0], [2.0, 1.0, 1.5]]])
TOWER = np.array([[[0.0, 0.0, 0.0], [4.0, 4.0, 2.0]], [[1.0, 1.0, 2.0], [3.0, 3.0, 4.0]]])  # box on a box


def _distance_to_box_edges(p, lo, hi):
    """Naive distance to the 12 edges of one box: loop over the edges."""
    best = np.full(len(p), np.inf)
    for a in range(3):
        t1, t2 = [t for t in range(3) if t != a]
        for u in (lo[t1], hi[t1]):
            for v in (lo[t2], hi[t2]):
                along = np.clip(p[:, a], lo[a], hi[a]) - p[:, a]
                best = np.minimum(best, np.sqrt(along**2 + (p[:, t1] - u) ** 2 + (p[:, t2] - v) ** 2))
    return best


def test_single_box_labels_exact():
    cloud = synthetic.sample_box_union(CUBE, n_points=3000, seed=3, delta=1.5)
    lo, hi = CUBE[0]
    on_face = np.isclose(cloud.points, lo) | np.isclose(cloud.points, hi)
    assert (on_face.sum(axis=1) >= 1).all()
    expected = _distance_to_box_edges(cloud.points, lo, hi) <= cloud.delta
    np.testing.assert_array_equal(cloud.edge_mask, expected)
    assert 0 < cloud.edge_mask.sum() < 3000
    assert cloud.delta == pytest.approx(1.5 * cloud.resolution)


def test_concave_junction_labelled_and_no_internal_points():
    cloud = synthetic.sample_box_union(TOWER, n_points=4000, seed=0, delta=1.0)
    p = cloud.points
    # Nothing inside the union, nothing on the shared patch z = 2 under the upper box.
    for lo, hi in TOWER:
        assert not ((p > lo + 1e-12) & (p < hi - 1e-12)).all(axis=1).any()
    hidden = np.isclose(p[:, 2], 2.0) & (p[:, :2] > 1).all(1) & (p[:, :2] < 3).all(1)
    assert not hidden.any()
    # Points of the base's top face near the concave edge at x = 1 (1 <= y <= 3) are edges.
    near = np.isclose(p[:, 2], 2.0) & (np.abs(p[:, 0] - 1) < 0.5 * cloud.delta) & (p[:, 1] > 1.2) & (p[:, 1] < 2.8)
    assert near.any() and cloud.edge_mask[near].all()
    # Base box 12 edges (40), upper box 8 convex edges (16) and its 4 concave bottom edges (8).
    seg = synthetic.sharp_edges(TOWER)
    assert np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1).sum() == pytest.approx(40 + 16 + 8)


def test_uniform_density_across_faces():
    cloud = synthetic.sample_box_union(TOWER, n_points=20000, seed=1)
    area_top = 4 * 4 - 2 * 2 + 2 * 2  # base top (outer part) + upper box top
    top = np.isclose(cloud.points[:, 2], 2.0) | np.isclose(cloud.points[:, 2], 4.0)
    total = 2 * (16 + 8 + 8) + 4 * 2 * 2 + 4 - 4  # base surface + upper sides + top - shared
    assert top.mean() == pytest.approx(area_top / total, abs=0.015)


def test_coplanar_seam_not_sharp():
    two = np.array([[[0.0, 0, 0], [1, 1, 1]], [[1.0, 0, 0], [2, 1, 1]]])
    seg = synthetic.sharp_edges(two)
    assert not (np.isclose(seg[:, :, 0], 1.0).all(axis=1)).any()


def test_rotation_and_noise_keep_labels():
    base = hgjax.eval.box_union_cloud(seed=2, n_points=1500)
    moved = hgjax.eval.box_union_cloud(seed=2, n_points=1500, rotate=True, noise=0.2)
    np.testing.assert_array_equal(base.edge_mask, moved.edge_mask)
    assert not np.allclose(base.points, moved.points)
    assert base.points.dtype == np.float64
    again = hgjax.eval.box_union_cloud(seed=2, n_points=1500, rotate=True, noise=0.2)
    np.testing.assert_array_equal(moved.points, again.points)


def test_default_edge_fraction_near_paper():
    frac = np.mean([c.edge_mask.mean() for c in hgjax.eval.synthetic_set()])
    assert frac == pytest.approx(0.0765, abs=0.004)


def test_box_surface():
    p = hgjax.eval.box_surface(500, 7)
    assert p.shape == (500, 3) and p.dtype == np.float64
    on = np.isclose(p, 0) | np.isclose(p, [1.0, 0.8, 0.6])
    assert on.any(axis=1).all()
    np.testing.assert_array_equal(p, hgjax.eval.box_surface(500, 7))


def test_load_labelled():
    path = ROOT.parent / "shared" / "data" / "labelled" / "pced_cubefractal2.gt.ply"
    if not path.exists():
        pytest.skip("labelled data not available")
    cloud = hgjax.eval.load_labelled(path)
    assert cloud.points.shape == (7212, 3) and int(cloud.edge_mask.sum()) == 479
    assert int(hgjax.eval.load_labelled(path, scheme="pcednet").edge_mask.sum()) == 479


def test_load_labelled_bazazian(tmp_path):
    """Bazazian et al.'s scheme: white non-edge, any other colour (red, yellow) edge."""
    import trimesh

    pts = np.random.default_rng(0).random((5, 3))
    rgba = np.array([[255, 255, 255, 255], [255, 0, 0, 255], [255, 255, 0, 255], [255, 255, 255, 255],
                     [255, 0, 0, 255]], dtype=np.uint8)
    path = tmp_path / "baz.gt.ply"
    trimesh.PointCloud(pts, colors=rgba).export(path)
    cloud = hgjax.eval.load_labelled(path)
    assert cloud.edge_mask.tolist() == [False, True, True, False, True]
    assert hgjax.eval.load_labelled(path, scheme="bazazian").edge_mask.tolist() == cloud.edge_mask.tolist()
    with pytest.raises(ValueError, match="not one of the labels"):
        hgjax.eval.load_labelled(path, scheme="pcednet")
    with pytest.raises(ValueError, match="scheme"):
        hgjax.eval.load_labelled(path, scheme="other")
    real = ROOT.parent / "shared" / "data" / "labelled" / "baz_twoplane45.gt.ply"
    if real.exists():
        assert int(hgjax.eval.load_labelled(real).edge_mask.sum()) == 294


def test_metrics_hand_computed():
    pts = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0], [4, 0, 0], [5, 0, 0]])
    mask = np.array([True, True, True, False, False, False])
    kept = np.array([0, 3])
    m = hgjax.eval.edge_metrics(pts, mask, kept, resolution=0.5)
    assert (m["tp"], m["precision"], m["recall"]) == (1, 0.5, pytest.approx(1 / 3))
    assert m["f1"] == pytest.approx(2 * 0.5 / 3 / (0.5 + 1 / 3))
    assert m["best_f1"] == pytest.approx(2 * 2 / 5) and m["f1_over_best"] == 0.5
    assert m["mean_distance"] == pytest.approx(0.5) and m["mean_distance_res"] == pytest.approx(1.0)
    # ranking: kept order first (0 then 3), the other four tied last: AP = (1*1/3) + ... grouped.
    assert m["average_precision"] == pytest.approx(1 / 3 * 1 + 2 / 3 * 3 / 6)
    assert "mcc" not in m
    m3 = hgjax.eval.edge_metrics(pts, mask, np.array([0, 1, 4]), scores=np.arange(6.0)[::-1])
    # tp=2 fp=1 fn=1 tn=2: mcc = (4 - 1) / sqrt(3 * 3 * 3 * 3)
    assert m3["mcc"] == pytest.approx(3 / 9)
    assert m3["average_precision"] == pytest.approx(1.0)


def test_metrics_errors():
    pts = np.zeros((3, 3))
    with pytest.raises(ValueError, match="no edge"):
        hgjax.eval.edge_metrics(pts, np.zeros(3, bool), np.array([0]))
    with pytest.raises(ValueError, match="unique"):
        hgjax.eval.edge_metrics(pts, np.ones(3, bool), np.array([0, 0]))


@pytest.mark.full
def test_quick_bench(tmp_path):
    sys.path.insert(0, str(ROOT / "bench"))
    import edge_table

    edge_table.main(["--quick", "--out", str(tmp_path)])
    text = (tmp_path / "edge_table.md").read_text()
    assert "Command: `python bench/edge_table.py --quick" in text and "hkc-inv" in text
    table1 = text[text.index("## Paper Table 1"):text.index("## Random regime")]
    for label in ("hkc-ref", "gfr-ref", "pca_ac", "hkc (default)", "lhf (default)", "grid: reproduced?"):
        assert f"| {label} |" in table1 or label in table1
    assert table1.count("| 0.1 |") == 12  # six methods, reference and default rows
    assert (tmp_path / "edge_noise.png").stat().st_size > 0 and (tmp_path / "edge_ratio.png").exists()


def test_published_per_model_rows_are_copied_and_compared_on_matching_labels(tmp_path, monkeypatch):
    """bench/published.py copies a supplement's rows of the shared models; edge_detectors.per_model compares a row
    only where its counts give one of our columns (N and positives)."""
    sys.path.insert(0, str(ROOT / "bench"))
    import edge_detectors
    import published

    supp = tmp_path / "supp" / "scripts"
    (supp / "3dmodels" / "default").mkdir(parents=True)
    (supp / "3dmodels" / "default" / "nameToId.json").write_text('{"CubeFractal2.ply": 1, "TwoPlane90.ply": 0}')
    (supp / "utilsmodule.py").write_text('methods_descr = {"pced": "PCED (D)"}\nmethods_nbclasses = {"pced": "3"}\n')
    for dataset, rows in (("default", ["0.9 0.8 0.5 30 5 65 0", "1 0.5 0.7 10 0 88 2"]),
                          ("abc", ["0 0 0 1 1 1 1"] * 7033 + ["0.9 0.9 0.8 8 1 90 1"])):
        (supp / "data" / dataset).mkdir(parents=True)
        (supp / "data" / dataset / "pced.txt").write_text("#header\n#columns\n" + "\n".join(rows) + "\n")
    rows = published.extract(tmp_path / "supp")
    got = {r["model"]: (r["name"], r["classes"], r["mcc"], r["tp"], r["fn"], r["row"]) for r in rows}
    assert got == {"pced_abc_7033": ("PCED (D)", "3", 0.8, 8, 1, 7033),
                   "pced_cubefractal2": ("PCED (D)", "3", 0.7, 10, 2, 1),
                   "pced_twoplane90": ("PCED (D)", "3", 0.5, 30, 0, 0)}
    csv_path = tmp_path / "per_model.csv"
    published.main([str(tmp_path / "supp"), "--out", str(csv_path)])
    real = {"pced_abc_7033": {"mss": (0.9, 0.95), "ea": (0.2, 0.3)},
            "pced_cubefractal2": {"mss": (0.6, 0.7), "ea": (0.75, 0.7)},
            "pced_cubefractal2 edge+near": {"mss": (0.65, 0.7)}, "pced_twoplane90": {"mss": (0.4, 0.5)}}
    sizes = {"pced_abc_7033": (100, 9), "pced_cubefractal2": (100, 12), "pced_cubefractal2 edge+near": (100, 30),
             "pced_twoplane90": (100, 3)}
    monkeypatch.setattr(edge_detectors, "PER_MODEL", csv_path)
    table, summary = edge_detectors.per_model(real, sizes)
    by_model = {r[0]: r for r in table}
    assert by_model["pced_abc_7033"][3:] == ["edge", "0.800", "**0.900**", "mss 0.900"]
    assert by_model["pced_cubefractal2"][3:] == ["edge", "0.700", "0.600", "ea 0.750"]
    assert by_model["pced_twoplane90"][3:] == ["other labels (30 of 100)", "0.500", "", ""]  # 30 positives: no column
    assert summary.startswith("1 of 2 comparable") and "PCED (D) on pced_cubefractal2 (0.700 against 0.600)" in summary
