"""Every scoring method as an edge detector: MCC keeping exactly E points and average precision.

Columns (issue 22):

* (a) the five labelled clouds of ../shared/data/labelled with their edge-only labels, and the
  PCEDNet clouds again with edge + near-edge points as positives;
* (b) the same clouds with Gaussian noise of 0.25 / 0.5 / 1 spacing (spacing = intrinsic
  resolution), isotropic, and along the normals (estimated by PCA of the 16 nearest points of
  the clean cloud, the same for every method); labels unchanged;
* (c) box unions (``hgjax.eval.synthetic_set``, random and grid sampling, noise p = 0 / 0.2 /
  0.5 / 1 spacing), labels within one spacing of a sharp edge;
* (d) the published figures of PCEDNet's supplement beside ours: the per-set means that the issue
  quotes, and every detector's per-model MCC on the three models we share with it
  (bench/results/pcednet_per_model.csv, written by ``bench/published.py``), each beside MSS's MCC at
  E on the same labels (a row is compared where its TP + FP + TN + FN is the cloud's N and its
  TP + FN the positives of one of our label columns, edge-only or edge + near).

Every method runs with its defaults (GFR with ``mode="top"``, its deterministic ranking). MCC:
keep exactly E = the number of positives (``hgjax.keep`` at ratio E / N). AP: the full keep
order (``hgjax.keep`` at ratio 1) as the ranking. Nothing is tuned here; the labelled clouds
are only reported.

Usage (from the repository root):
  python bench/edge_detectors.py                      # writes bench/results/edge_detectors.md
  python bench/edge_detectors.py --quick --out /tmp/x # smoke run
"""

from __future__ import annotations

import argparse
import csv
import pathlib
import sys
import time

import jax
import numpy as np
from scipy.spatial import cKDTree

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import hgjax  # noqa: E402
import _report  # noqa: E402

jax.config.update("jax_enable_x64", True)

METHODS = ("mss", "ea", "pca_ac", "gfr", "hkc", "hkf", "lhf")
LABELLED = ROOT.parent / "shared" / "data" / "labelled"
NOISES = (0.25, 0.5, 1.0)
SYNTHETIC_NOISES = (0.0, 0.2, 0.5, 1.0)
SYNTHETIC = {"random": {"n_shapes": 6, "n_points": 6000}, "grid": {"n_shapes": 6, "n_points": 8000}}
QUICK_SYNTHETIC = {"random": {"n_shapes": 1, "n_points": 2000}, "grid": {"n_shapes": 1, "n_points": 2000}}
NOISE_SEED = 2022
PER_MODEL = ROOT / "bench" / "results" / "pcednet_per_model.csv"
# PCEDNet supplement (Himeur et al., ACM TOG 41(1), 2022), mean MCC over the shipped models of each
# set, as quoted in issue 22; its per-model figures are in PER_MODEL.
PUBLISHED = {
    "EC-Net": (".465", ".346", ".310"),
    "covariance detector": (".441", "-", ".383"),
    "PCEDNet": (".689", ".357", ".380"),
    "PCEDNet, best variant": (".826", ".394", ".477"),
}


def detect(points, positives, method, candidate=None):
    """(MCC keeping exactly E, AP) of one method's default ranking on one labelled cloud; ``method`` "candidate":
    ``candidate(points) -> (N,)`` scores, higher is sharper."""
    e, n = int(positives.sum()), len(points)
    if method == "candidate":
        scores = candidate(points)
        kept, order = hgjax.top_k(scores, e), hgjax.top_k(scores, n)
    else:
        kept, order, scores = _ranked(points, e, method)
    rank = np.empty(n)
    rank[order] = np.arange(n, 0, -1)
    m = hgjax.eval.edge_metrics(points, positives, kept, scores=rank, resolution=1.0)
    assert m["n_kept"] == e
    return m["mcc"], m["average_precision"]


def _ranked(points, e: int, method: str):
    """(the E kept indices, the full keep order, the scores) of a registered method."""
    n = len(points)
    params = {"mode": "top"} if method == "gfr" else {}
    entry = hgjax.METHODS[method]
    scores = np.asarray(hgjax.score(hgjax.neighbourhoods(points, method), method))
    kept = hgjax.keep(scores, count=e, method=method, **params)
    if entry.combine is not None:  # LHF ranks its two lengths combined at the kept count E
        scores = entry.combine(scores, e)
        order = hgjax.top_k(scores, n, largest=entry.largest)
    else:
        order = hgjax.keep(scores, 1.0, method=method, **params)
    return kept, order, scores


def pca_normals(points, k=16):
    _, idx = cKDTree(points).query(points, k=k)
    x = points[idx] - points[idx].mean(axis=1, keepdims=True)
    return np.linalg.eigh(np.einsum("nki,nkj->nij", x, x))[1][:, :, 0]


def noisy(points, p, kind, spacing, normals, seed):
    rng = np.random.default_rng([NOISE_SEED, seed])
    if kind == "iso":
        return points + p * spacing * rng.standard_normal(points.shape)
    return points + p * spacing * rng.standard_normal((len(points), 1)) * normals


def md(header, rows):
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)] + [
        "| " + " | ".join(str(x) for x in r) + " |" for r in rows]


def cell(v, other=None):
    """MCC / AP to 3 decimals, or to 6 where they round like ``other``'s (a difference below the rounding)."""
    digits = 6 if other is not None and cell(v) == cell(other) else 3
    return f"{v[0]:.{digits}f} / {v[1]:.{digits}f}"


def bold_best(rows, first=1):
    """Bold the best MCC and the best AP of every column (rows: [name, (mcc, ap), ...])."""
    out = [[r[0]] for r in rows]
    for j in range(first, len(rows[0])):
        best = [max(r[j][i] for r in rows) for i in (0, 1)]
        for r, o in zip(rows, out):
            parts = [f"**{r[j][i]:.3f}**" if r[j][i] >= best[i] - 1e-12 else f"{r[j][i]:.3f}" for i in (0, 1)]
            o.append(" / ".join(parts))
    return out


def main(argv=None, candidate=None):
    """Writes the report; returns (real, synthetic): {column: {method: (MCC, AP)}}. ``candidate(points) -> (N,)``:
    a detector under trial (bench/mss_training), reported as the method "candidate" beside the others."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="tiny smoke run")
    parser.add_argument("--out", type=pathlib.Path, default=ROOT / "bench" / "results")
    parser.add_argument("--methods", default=",".join(METHODS),
                        help="comma-separated methods to run (default all; mss and ea are always run)")
    args = parser.parse_args(argv)
    methods = tuple(m for m in METHODS if m in {"mss", "ea", *args.methods.split(",")})
    methods += ("candidate",) * (candidate is not None)
    t0 = time.time()
    files = sorted(LABELLED.glob("*.gt.ply"))[: 2 if args.quick else None]
    noises = NOISES[:1] if args.quick else NOISES
    real = {}  # column -> {method: (mcc, ap)}
    sizes = {}  # column -> (N, positives)
    for f in files:
        cloud = hgjax.eval.load_labelled(f)
        pts, spacing = cloud.points, cloud.resolution
        cols = {f"{cloud.name}": (pts, cloud.edge_mask)}
        if cloud.name.startswith("pced"):
            near = hgjax.eval.load_labelled(f, scheme="pcednet")
            rgb_near = _near_edge(f)
            cols[f"{cloud.name} edge+near"] = (pts, near.edge_mask | rgb_near)
        normals = pca_normals(pts)
        for kind in ("iso", "normal"):
            for i, p in enumerate(noises):
                cols[f"{cloud.name} {kind} {p}"] = (noisy(pts, p, kind, spacing, normals, i + 10 * (kind == "normal")),
                                                    cloud.edge_mask)
        for col, (q, pos) in cols.items():
            real[col] = {m: detect(q, pos, m, candidate) for m in methods}
            sizes[col] = (len(q), int(pos.sum()))
        print(f"{cloud.name}: {time.time() - t0:.0f} s", flush=True)
    synthetic = {}
    for regime, size in (QUICK_SYNTHETIC if args.quick else SYNTHETIC).items():
        for p in SYNTHETIC_NOISES[:2] if args.quick else SYNTHETIC_NOISES:
            clouds = hgjax.eval.synthetic_set(regime=regime, noise=p, **size)
            res = [{m: detect(c.points, c.edge_mask, m, candidate) for m in methods} for c in clouds]
            synthetic[f"{regime} p={p}"] = {m: tuple(np.mean([r[m] for r in res], axis=0)) for m in methods}
            print(f"{regime} p={p}: {time.time() - t0:.0f} s", flush=True)

    names = [f.name.removesuffix(".gt.ply") for f in files]
    clean_cols = [c for c in real if c in names or c.endswith("edge+near")]
    mean = lambda cols, m: tuple(np.mean([real[c][m] for c in cols], axis=0))  # noqa: E731
    noise_cols = {f"{kind} {p}": [f"{n} {kind} {p}" for n in names] for kind in ("iso", "normal") for p in noises}
    table = ["## (a) labelled clouds, clean: MCC at E / AP", ""]
    table += md(["method"] + clean_cols + [f"mean (edge-only, {len(names)} clouds)"],
                bold_best([[m] + [real[c][m] for c in clean_cols] + [mean(names, m)] for m in methods]))
    table += ["", "## (b) labelled clouds with noise (std = p spacings): MCC at E / AP, mean over the clouds", ""]
    table += md(["method"] + list(noise_cols), bold_best([[m] + [mean(cs, m) for cs in noise_cols.values()]
                                                           for m in methods]))
    table += ["", "Per cloud:", ""]
    noisy_cols = [c for c in real if c not in clean_cols]
    table += md(["method"] + noisy_cols, bold_best([[m] + [real[c][m] for c in noisy_cols] for m in methods]))
    table += ["", "## (c) box unions (`synthetic_set`, axis-aligned): MCC at E / AP, mean over the shapes", ""]
    table += md(["method"] + list(synthetic), bold_best([[m] + [synthetic[c][m] for c in synthetic]
                                                          for m in methods]))
    published, above = per_model(real, sizes)
    table += ["", "## (d) published detectors (PCEDNet supplement)", "",
              "Per model: every detector of the supplement on the three models we share with it "
              "(bench/results/pcednet_per_model.csv, from `python bench/published.py`), beside MSS's MCC at E "
              "on the same labels, told by the row's counts (positives = edge: the sharp class; edge+near: sharp "
              "and near-edge). The published detectors threshold their classifiers instead of keeping exactly "
              "E points. Rows whose counts match none of our columns are listed without a comparison.", ""]
    table += md(["model", "detector (supplement's name)", "classes", "labels", "published MCC", "mss MCC at E",
                 "best hgjax method, MCC at E"], published)
    table += ["", "Per set, mean MCC over the set's models, as quoted in issue 22 (other models than ours):", ""]
    table += md(["detector", "ABC (mean)", "noisy ABC (mean)", "SHREC (mean)"],
                [[k, *v] for k, v in PUBLISHED.items()])
    wins = {c: all(a >= b for a, b in zip(real[c]["mss"], real[c]["ea"])) for c in real}
    below = [f"{c} ({'MCC' if real_or_syn[c]['mss'][0] < real_or_syn[c]['ea'][0] else 'AP'} "
             f"{cell(real_or_syn[c]['mss'], real_or_syn[c]['ea'])} against EA "
             f"{cell(real_or_syn[c]['ea'], real_or_syn[c]['mss'])})"
             for real_or_syn in (real, synthetic) for c in real_or_syn
             if any(a < b for a, b in zip(real_or_syn[c]["mss"], real_or_syn[c]["ea"]))]
    table += ["", f"Run time {time.time() - t0:.0f} s (2 shared cores)."]
    paragraphs = [
        "MCC keeping exactly E points (E = the number of positives) and average precision of the full keep order, "
        "for every scoring method with its defaults (GFR `mode=\"top\"`). Bold: best of the column. Labelled "
        "clouds: PCEDNet colours near-edge points (255,196,93); in the edge-only columns they count as non-edge "
        "(as in bench/results/edge_defaults.md), in the `edge+near` columns as positives. Noise: std = p x the "
        "intrinsic resolution, isotropic or along PCA normals of the clean cloud (16 neighbours), one fixed seed "
        "per column; labels unchanged. Box unions: `hgjax.eval.synthetic_set(regime, noise=p)` "
        f"({', '.join(f'{r}: {s}' for r, s in (QUICK_SYNTHETIC if args.quick else SYNTHETIC).items())}).",
        "MSS (`hgjax.scores.mss`) is a small perceptron trained by `bench/mss_training/train_edges.py` on "
        "synthetic shapes only (`hgjax.eval.solids` and box unions of other seeds than (c)'s); nothing in this "
        "file was tuned on the labelled clouds. "
        f"MSS >= EA in MCC and AP: {sum(map(bool, wins.values()))} of {len(wins)} "
        "labelled columns (a, b). Every column (per cloud and synthetic) where MSS is below EA in MCC or AP: "
        + ("; ".join(below) if below else "none") + ".",
        f"Published per-model figures (d): MSS is above {above}.",
    ]
    _report.write(args.out / "edge_detectors.md", "edge_detectors.py", argv, title="Edge detectors: every scoring "
                  "method, labelled and synthetic clouds", paragraphs=paragraphs, table=table)
    return real, synthetic


def per_model(real, sizes):
    """Rows of (d) from ``PER_MODEL`` and a summary: above how many comparable published figures MSS is.

    A published row is compared with the column of the same model whose N and positives its
    counts give (MSS's MCC at E there, and the best of every method run); the others keep their
    figure with "other labels (P positives of N)".
    """
    with PER_MODEL.open() as f:
        rows = list(csv.DictReader(line for line in f if not line.startswith("#")))
    out, wins, below = [], 0, []
    for r in sorted((r for r in rows if r["model"] in real), key=lambda r: (r["model"], -float(r["mcc"]))):
        tp, fp, tn, fn = (int(r[k]) for k in ("tp", "fp", "tn", "fn"))
        col = next((c for c in (r["model"], f"{r['model']} edge+near") if sizes.get(c) == (tp + fp + tn + fn, tp + fn)),
                   None)
        mcc = float(r["mcc"])
        if col is None:
            out.append([r["model"], r["name"], r["classes"], f"other labels ({tp + fn} of {tp + fp + tn + fn})",
                        f"{mcc:.3f}", "", ""])
            continue
        ours = real[col]["mss"][0]
        wins += ours > mcc
        if ours <= mcc:
            below.append(f"{r['name']} on {col} ({mcc:.3f} against {ours:.3f})")
        best = max(real[col], key=lambda m: real[col][m][0])
        out.append([r["model"], r["name"], r["classes"], "edge+near" if col.endswith("edge+near") else "edge",
                    f"{mcc:.3f}", f"**{ours:.3f}**" if ours > mcc else f"{ours:.3f}",
                    f"{best} {real[col][best][0]:.3f}"])
    summary = (f"{wins} of {wins + len(below)} comparable published per-model figures; at or below: "
               + ("; ".join(below) if below else "none"))
    return out, summary


def _near_edge(path):
    """(N,) bool: PCEDNet's near-edge colour (255, 196, 93) in a labelled PLY."""
    import trimesh

    rgb = np.asarray(trimesh.load(path, file_type="ply").colors)[:, :3].astype(int)
    return (rgb == np.array(hgjax.eval.synthetic.LABEL_NEAR_EDGE)).all(axis=1)


if __name__ == "__main__":
    main()
