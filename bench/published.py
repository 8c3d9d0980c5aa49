"""The published per-model figures of PCEDNet's supplement for the shared labelled models.

Himeur et al., "PCEDNet: A Lightweight Neural Network for Fast and Interactive Edge Detection in
3D Point Clouds", ACM TOG 41(1), 2022; supplement: github.com/STORM-IRIT/pcednet-supp. Its
``scripts/data/<set>/<detector>.txt`` hold one row per model (precision, recall, MCC, TP, FP, TN,
FN). This script copies the rows of the three models that ../shared/data/labelled shares with it
into a CSV that ``bench/edge_detectors.py`` puts beside ours (issue 22 item 2 (d)):

* ``pced_abc_7033``: set ``abc``, row 7033 (the rows of that set are indexed by the ABC model id);
* ``pced_cubefractal2`` and ``pced_twoplane90``: set ``default``, the rows that
  ``scripts/3dmodels/default/nameToId.json`` gives CubeFractal2.ply and TwoPlane90.ply.

Nothing is scored here and no cloud of the supplement is read: the figures are the detectors'
own, each thresholding its classifier (not keeping exactly E points), on labels that may be the
sharp class alone or sharp + smooth (near-edge). ``bench/edge_detectors.py`` tells which from the
row's counts: it compares a row only where TP + FP + TN + FN is the shared cloud's N and TP + FN
the positives of one of its label columns.

Usage (from the repository root; SUPP a checkout of the supplement):
  python bench/published.py SUPP      # writes bench/results/pcednet_per_model.csv
"""

from __future__ import annotations

import argparse
import ast
import csv
import json
import pathlib
import subprocess

ROOT = pathlib.Path(__file__).resolve().parents[1]
OUT = ROOT / "bench" / "results" / "pcednet_per_model.csv"
MODELS = {"pced_abc_7033": ("abc", 7033), "pced_cubefractal2": ("default", "CubeFractal2.ply"),
          "pced_twoplane90": ("default", "TwoPlane90.ply")}
FIELDS = ("model", "detector", "name", "classes", "mcc", "tp", "fp", "tn", "fn", "source", "row")


def _names(supp: pathlib.Path) -> tuple[dict, dict]:
    """The supplement's long detector names and class counts (``scripts/utilsmodule.py``' dicts)."""
    tree = ast.parse((supp / "scripts" / "utilsmodule.py").read_text())
    found = {t.id: ast.literal_eval(node.value) for node in tree.body if isinstance(node, ast.Assign)
             for t in node.targets if isinstance(t, ast.Name) and t.id in ("methods_descr", "methods_nbclasses")}
    return found["methods_descr"], found["methods_nbclasses"]


def _rows(path: pathlib.Path) -> list[list[str]]:
    return [line.split() for line in path.read_text().splitlines() if line.strip() and not line.startswith("#")]


def extract(supp: pathlib.Path) -> list[dict]:
    """One dict per (shared model, supplement detector) row, in ``FIELDS``."""
    descr, classes = _names(supp)
    out = []
    for model, (dataset, key) in MODELS.items():
        row = key if isinstance(key, int) else json.loads(
            (supp / "scripts" / "3dmodels" / dataset / "nameToId.json").read_text())[key]
        for path in sorted((supp / "scripts" / "data" / dataset).glob("*.txt")):
            rows = _rows(path)
            if row >= len(rows):
                continue
            precision, recall, mcc, *counts = rows[row][:7]
            out.append(dict(zip(FIELDS, (model, path.stem, descr.get(path.stem, path.stem), classes.get(path.stem, ""),
                                         float(mcc), *(int(float(c)) for c in counts),
                                         path.relative_to(supp).as_posix(), row))))
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("supp", type=pathlib.Path, help="a checkout of github.com/STORM-IRIT/pcednet-supp")
    parser.add_argument("--out", type=pathlib.Path, default=OUT)
    args = parser.parse_args(argv)
    commit = subprocess.run(["git", "-C", str(args.supp), "rev-parse", "HEAD"], capture_output=True,
                            text=True).stdout.strip() or "unknown"
    rows = extract(args.supp)
    with args.out.open("w", newline="") as f:
        f.write(f"# Command: python bench/published.py <checkout>; github.com/STORM-IRIT/pcednet-supp at {commit}\n")
        writer = csv.DictWriter(f, FIELDS)
        writer.writeheader()
        writer.writerows(rows)
    print(f"wrote {args.out} ({len(rows)} rows)")


if __name__ == "__main__":
    main()
