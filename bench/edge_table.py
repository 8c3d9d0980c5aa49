"""Edge benchmark (paper Table 1 protocol), noise sweep, ratio sweep and labelled real clouds.

Usage (from the repository root):
  python bench/edge_table.py              # full tables and figures into bench/results/
  python bench/edge_table.py --defaults   # LHF lengths / HKC-HKF d_factor study
  python bench/edge_table.py --quick --out /tmp/x   # tiny smoke run (CI)
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import jax
import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

import hgjax  # noqa: E402
from _cases import method_runs, synthetic_clouds  # noqa: E402

jax.config.update("jax_enable_x64", True)

RATIO = 0.2
RATIOS = (0.05, 0.1, 0.2, 0.3, 0.4, 0.5)
PAPER_BEST = 0.5522
# Paper Table 1, F1 at noise 0 / 10 % / 20 %.
PAPER_F1 = {"hkc": (0.5497, 0.5485, 0.3697), "hkf": (0.5276, 0.5060, 0.2163),
            "lhf": (0.5166, 0.2075, 0.1299), "gfr": (0.5522, 0.5509, 0.3337),
            "ea": (0.5522, 0.5463, 0.5193), "pca_ac": (0.5418, 0.5117, 0.4941)}
# PCEDNet supplement, MCC on the labelled clouds (peers chose their own thresholds).
PUBLISHED_MCC = {
    "pced_abc_7033": "PCEDNet .978, EC-Net .711, FEE .687, covariance .595; top-E SV(k=16) .546",
    "pced_cubefractal2": "PCEDNet .909, EC-Net .772, covariance .840; top-E SV(k=16) .535",
    "pced_twoplane90": "PCEDNet .841, EC-Net .563, covariance .907; top-E SV(k=16) .357",
}
LABELLED = ROOT.parent / "shared" / "data" / "labelled"
KEYS = ("precision", "recall", "f1", "f1_over_best", "mean_distance_res", "average_precision")


def run_one(cloud, method, params, ratio):
    idx = hgjax.resample(cloud.points, ratio, method=method, key=jax.random.key(0), **params)
    return hgjax.eval.edge_metrics(cloud.points, cloud.edge_mask, idx, edge_points=cloud.edge_points,
                                   resolution=cloud.resolution)


def mean_metrics(clouds, method, params, ratio):
    rows = [run_one(c, method, params, ratio) for c in clouds]
    return {k: float(np.mean([r[k] for r in rows])) for k in KEYS + ("best_f1",)}


def md_table(header, rows):
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return out + ["| " + " | ".join(str(x) for x in r) + " |" for r in rows]


def plot(path, xs, series, xlabel, ylabel):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for i, (label, ys) in enumerate(series.items()):  # 10 colours, so vary the line style too
        ax.plot(xs, ys, marker="os^"[i // 10 % 3], linestyle=("-", "--", ":")[i // 10 % 3], label=label)
    ax.set(xlabel=xlabel, ylabel=ylabel)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def table(args, out, command):
    runs = method_runs()
    noises = hgjax.eval.NOISE_LEVELS if not args.quick else (0.0, 0.2)
    res = {}  # (rotate, noise, label) -> metrics
    t0 = time.time()
    for rotate in (False, True):
        for noise in noises:
            clouds = synthetic_clouds(n_shapes=args.n_shapes, n_points=args.n_points, rotate=rotate, noise=noise)
            for label, method, params in runs:
                res[rotate, noise, label] = mean_metrics(clouds, method, params, RATIO)
            print(f"rotate={rotate} noise={noise}: {time.time() - t0:.0f} s", flush=True)
    best = np.mean([c.edge_mask.mean() for c in synthetic_clouds(n_shapes=args.n_shapes, n_points=args.n_points,
                                                                 rotate=False, noise=0.0)])
    lines = [f"# Edge benchmark (paper Table 1 protocol)", "", f"Command: `{command}`", "",
             f"Synthetic set: {args.n_shapes} unions of axis-aligned boxes (`hgjax.eval.synthetic_set`), "
             f"{args.n_points} points each, edge band delta = {hgjax.eval.DEFAULT_DELTA} resolution, mean edge "
             f"fraction {100 * best:.2f} % (paper 7.65 %). Ratio {RATIO}; random methods use "
             "`jax.random.key(0)`. Noise: Gaussian, std = p x intrinsic resolution. The paper's '10 %' / '20 %' "
             "are undefined; under our reading they are the p = 0.1 / 0.2 columns. Values are means over "
             "shapes. F1/best divides by the best F1 reachable keeping the same number of points "
             "(paper best .5522); both are means over shapes of per-shape values. `-inv` / `-ref`: `variant='invariant'` / `'reference'`.", ""]
    for rotate in (False, True):
        lines += [f"## {'Rotated' if rotate else 'Axis-aligned'} shapes: F1 (F1/best) by noise p", ""]
        header = ["method"] + [f"p={p}" for p in noises] + ["paper F1/best at 0 / 10 % / 20 %",
                                                              "AP (p=0)", "mean dist / res (p=0)"]
        rows = []
        for label, method, _ in runs:
            paper = PAPER_F1.get(method)
            ref = " / ".join(f"{v / PAPER_BEST:.3f}" for v in paper) if paper else "-"
            r0 = res[rotate, noises[0], label]
            rows.append([label] + [f"{res[rotate, p, label]['f1']:.3f} ({res[rotate, p, label]['f1_over_best']:.3f})"
                                   for p in noises] + [ref, f"{r0['average_precision']:.3f}",
                                                       f"{r0['mean_distance_res']:.2f}"])
        lines += md_table(header, rows) + [""]
        plot(out / f"edge_noise{'_rotated' if rotate else ''}.png", noises,
             {label: [res[rotate, p, label]["f1_over_best"] for p in noises] for label, _, _ in runs},
             "noise p (std / resolution)", f"F1 / best ({'rotated' if rotate else 'axis-aligned'})")
    lines += [f"Figures: `edge_noise.png`, `edge_noise_rotated.png` (F1/best against noise per method).", ""]
    lines += real_clouds(runs) if not args.quick else []
    lines += ratio_sweep(args, runs, out)
    lines += [f"Total time: {time.time() - t0:.0f} s on this machine.", ""]
    (out / "edge_table.md").write_text("\n".join(lines))


def real_clouds(runs):
    lines = ["## Labelled real clouds (PCEDNet ground truth): MCC keeping exactly E points", "",
             "Near-edge points count as non-edge. hgjax is TOLD E (ratio = E / N) and keeps its top E points; "
             "the published detectors chose their own thresholds, so this favours hgjax.", ""]
    files = sorted(LABELLED.glob("*.gt.ply"))
    clouds = [hgjax.eval.load_labelled(f) for f in files]
    header = ["method"] + [f"{c.name} (E={int(c.edge_mask.sum())}/{len(c.points)})" for c in clouds]
    rows = []
    for label, method, params in runs:
        row = [label]
        for c in clouds:
            e = int(c.edge_mask.sum())
            r = run_one(c, method, params, e / len(c.points))
            row.append(f"{r['mcc']:.3f}" if "mcc" in r else f"(kept {r['n_kept']} != E)")
        rows.append(row)
    rows.append(["published"] + [PUBLISHED_MCC.get(c.name, "-") for c in clouds])
    return lines + md_table(header, rows) + [""]


def ratio_sweep(args, runs, out):
    ratios = RATIOS if not args.quick else (0.1, 0.3)
    clouds = synthetic_clouds(n_shapes=args.n_shapes, n_points=args.n_points, rotate=False, noise=0.0)
    res = {(label, r): mean_metrics(clouds, m, p, r) for label, m, p in runs for r in ratios}
    lines = ["## Ratio sweep (axis-aligned, noise 0): F1 (F1/best)", ""]
    rows = [[label] + [f"{res[label, r]['f1']:.3f} ({res[label, r]['f1_over_best']:.3f})" for r in ratios]
            for label, _, _ in runs]
    rows.append(["best F1"] + [f"{res[runs[0][0], r]['best_f1']:.3f}" for r in ratios])
    plot(out / "edge_ratio.png", ratios, {label: [res[label, r]["f1"] for r in ratios] for label, _, _ in runs},
         "ratio alpha", "F1 (axis-aligned, noise 0)")
    return lines + md_table(["method"] + [f"alpha={r}" for r in ratios], rows) + ["", "Figure: `edge_ratio.png`.", ""]


def defaults(args, out, command):
    """Parameter study: F1 on the synthetic set and MCC on the labelled clouds per setting."""
    lengths = [(3, 6), (4, 8), (6, 12), (8, 16), (12, 24)] if not args.quick else [(4, 8)]
    factors = (1.0, 1.3, 1.6, 2.0, 2.5, 3.0, 4.0) if not args.quick else (1.3, 2.0)
    settings = [(rot, p) for rot in (False, True) for p in (0.0, 0.2)]
    sets = {s: synthetic_clouds(n_shapes=args.n_shapes, n_points=args.n_points, rotate=s[0], noise=s[1])
            for s in settings}
    real = [] if args.quick else [hgjax.eval.load_labelled(f) for f in sorted(LABELLED.glob("*.gt.ply"))]
    candidates = [(f"lhf {v[:3]} lengths={ln}", "lhf", {"variant": v, "lengths": ln})
                  for v in ("invariant", "reference") for ln in lengths]
    # HKC's two variants are identical (REFERENCE.md: 1 - lam is constant on each eigenspace).
    candidates += [(f"{m} {v[:3]} d_factor={f}", m, {"variant": v, "d_factor": f})
                   for m, v in (("hkc", "invariant"), ("hkf", "invariant"), ("hkf", "reference")) for f in factors]
    rows = []
    for label, m, p in candidates:
        f1 = [mean_metrics(sets[s], m, p, RATIO)["f1"] for s in settings]
        mcc = [run_one(c, m, p, c.edge_mask.sum() / len(c.points))["mcc"] for c in real]
        both = [f"{(np.mean(f1) + np.mean(mcc)) / 2:.3f}"] if mcc else []
        rows.append([label] + [f"{v:.3f}" for v in f1] + [f"{np.mean(f1):.3f}"] + [f"{v:.3f}" for v in mcc]
                    + ([f"{np.mean(mcc):.3f}"] if mcc else []) + both)
        print(label, rows[-1][1:], flush=True)
    header = (["setting"] + [f"{'rot' if r else 'axis'} p={p}" for r, p in settings] + ["mean F1"]
              + [f"MCC {c.name}" for c in real] + (["mean MCC", "(F1 + MCC) / 2"] if real else []))
    lines = ["# Defaults study: F1 at ratio 0.2 on the synthetic edge set, MCC on the labelled clouds", "",
             f"Command: `{command}`", "",
             f"{args.n_shapes} shapes x {args.n_points} points, means over shapes. MCC keeps exactly E points "
             "(the true edge count) on each labelled cloud, as in edge_table.md.", "",
             "Rule for the defaults of the default variant: the largest (mean F1 + mean MCC) / 2; settings within "
             "0.01 of it count as tied and the cheapest of them (smallest lengths or d factor) wins.", ""]
    (out / "edge_defaults.md").write_text("\n".join(lines + md_table(header, rows) + [""]))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="tiny run (2 shapes, 600 points)")
    parser.add_argument("--defaults", action="store_true", help="parameter study into edge_defaults.md")
    parser.add_argument("--out", type=pathlib.Path, default=ROOT / "bench" / "results")
    parser.add_argument("--n-shapes", type=int, default=None)
    parser.add_argument("--n-points", type=int, default=None)
    args = parser.parse_args(argv)
    args.n_shapes = args.n_shapes or (2 if args.quick else 12)
    args.n_points = args.n_points or (600 if args.quick else hgjax.eval.DEFAULT_N_POINTS)
    args.out.mkdir(parents=True, exist_ok=True)
    command = "python bench/edge_table.py " + " ".join(sys.argv[1:] if argv is None else argv)
    (defaults if args.defaults else table)(args, args.out, command.strip())


if __name__ == "__main__":
    main()
