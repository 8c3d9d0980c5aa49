"""``hgjax compare`` and ``hgjax demo``: several methods on one cloud, tabulated and drawn.

``compare`` runs a list of methods on one input and prints a markdown table of their coverage
gaps (:func:`_coverage`, in units of the intrinsic resolution: :func:`_gap_unit`) and of the
share of sharp features they keep; with ``-o DIR`` it writes the table as compare.md and
compare.csv and the picture compare.png. ``demo`` samples a CAD part with known sharp edges
(:data:`BRACKET`), has every method keep as many points as lie on an edge, ranks the methods by
the share of edge points they keep and draws them. Pictures need matplotlib; without it a note
replaces them (:func:`_picture`).
"""

from __future__ import annotations

import csv
import os
import sys
from typing import TYPE_CHECKING

from hgjax.cli._common import (
    UsageError,
    _check_samples,
    _compute,
    _expand,
    _file,
    _key,
    _load,
    _progress,
    _refuse_stdout,
)

if TYPE_CHECKING:
    import numpy as np


def _coverage(points: np.ndarray, idx: np.ndarray) -> tuple[float, float]:
    """Mean and max distance from every point to its nearest kept point."""
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(points[idx]).query(points, k=1, workers=-1)
    return float(dist.mean()), float(dist.max())


def cmd_compare(args) -> None:
    import hgjax

    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    unknown = sorted(set(methods) - set(hgjax.METHODS))
    if unknown or not methods:
        raise UsageError(f"unknown method(s) {unknown}; expected a comma-separated subset of {sorted(hgjax.METHODS)}")
    inputs = _expand(args.inputs)
    if len(inputs) != 1:
        raise UsageError(f"compare takes one file; {args.inputs[0]} holds {len(inputs)}")
    (path,) = inputs
    _check_samples(args.samples, inputs, methods)
    if args.output is not None:
        _refuse_stdout(args.output)
        try:
            os.makedirs(args.output, exist_ok=True)
        except OSError as err:
            raise UsageError(f"cannot create the output directory {args.output}: {err.strerror}") from None
        if not os.access(args.output, os.W_OK | os.X_OK):
            raise UsageError(f"cannot write to {args.output}: the directory is not writable")
    data = _load(path, args)
    res = hgjax.intrinsic_resolution(data.points)
    unit, unit_name = _gap_unit(data.points, res)
    variation = hgjax.eval.feature_variation(data.points)
    rows, kept = [], {}
    key, progress = _key(args), _progress(args)
    for method in methods:
        _file(method)
        idx, _, seconds = _compute(hgjax.METHODS[method], data.points, args.ratio, {}, key, progress, args)
        mean, worst = _coverage(data.points, idx)
        kept[method] = idx
        share = f"{variation[idx].mean() / variation.mean():.2f}" if variation.mean() > 0 else "-"
        rows.append([method, idx.size, len(data), f"{seconds:.3f}", f"{mean / unit:.3f}", f"{worst / unit:.3f}",
                     share])
    header = ["method", "kept", "points", "seconds", f"mean gap ({unit_name})", f"max gap ({unit_name})",
              "feature share"]
    table = "\n".join(["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
                      + ["| " + " | ".join(str(c) for c in row) + " |" for row in rows])
    print(f"{path}: ratio {args.ratio}, resolution {res:.4g}. Gap: distance from a point to the nearest kept"
          " point (small: even coverage). Feature share: mean surface variation of the kept points over"
          " that of all points (above 1: sharp edges and corners kept preferentially; EA maximises it by"
          f" definition).\n\n{table}")
    if args.output is None:
        return
    with open(os.path.join(args.output, "compare.md"), "w") as fh:
        fh.write(table + "\n")
    with open(os.path.join(args.output, "compare.csv"), "w", newline="") as fh:
        csv.writer(fh).writerows([header] + rows)
    picture = _picture(data.points, kept, os.path.join(args.output, "compare.png"), args,
                       colors=data.attributes.get("colors"), title=os.path.basename(path))
    print(f"wrote compare.md, compare.csv{', compare.png' * bool(picture)} to {args.output}", file=sys.stderr)


def _gap_unit(points: np.ndarray, res: float) -> tuple[float, str]:
    """The unit of coverage gaps: the intrinsic resolution, else (a cloud whose points mostly
    coincide) the bounding-box diagonal, else 1."""
    import numpy as np

    if res > 0:
        return res, "res"
    diagonal = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
    return (diagonal, "diagonal") if diagonal > 0 else (1.0, "units")


def _picture(points, kept: dict, path: str, args, **style) -> bool:
    """Draw the kept points of each method over the grey cloud to ``path``; False, with a note,
    where matplotlib is missing."""
    from hgjax.plot import show_resampling

    try:
        show_resampling(points, kept, view=args.view, zoom=args.zoom, context=True, path=path, **style)
    except ImportError as err:
        print(f"no picture written: {err}", file=sys.stderr)
        return False
    return True


BRACKET = ((0, 0, 0, 16, 10, 2), (0, 0, 2, 3, 10, 10), (3, 4, 2, 7, 6, 6), (9, 2, 2, 13, 8, 5))
"""The demo's part, four boxes (lower and upper corners): a base plate, a wall at one end, a rib
between them and a block on the plate."""


def cmd_demo(args) -> None:
    import numpy as np

    import hgjax

    folder = os.path.dirname(os.path.abspath(args.output))
    if not os.access(folder, os.W_OK | os.X_OK):
        raise UsageError(f"cannot write the picture {args.output}: {folder} is not a writable folder")
    boxes = np.reshape(BRACKET, (-1, 2, 3)).astype(float)
    cloud = hgjax.eval.sample_box_union(boxes, n_points=args.n_points, seed=args.seed)
    edge = np.asarray(cloud.edge_mask)
    n, n_edge = edge.size, int(edge.sum())
    ratio = n_edge / n if args.ratio is None else args.ratio
    print(f"demo cloud: {n} points sampled at random on an L-bracket (a plate, a wall, a rib and a block);\n"
          f"{n_edge} of them ({100 * n_edge / n:.1f} %) lie within {cloud.delta / cloud.resolution:g} point spacings"
          " of a sharp edge.")
    key, progress = _key(args), _progress(args)
    kept, same, recall, seconds = {}, {}, {}, {}
    for method in sorted(hgjax.METHODS):
        _file(method)
        idx, _, seconds[method] = _compute(hgjax.METHODS[method], cloud.points, ratio, {}, key, progress, args)
        same[method] = next((m for m, other in kept.items() if np.array_equal(np.sort(other), np.sort(idx))), None)
        kept[method] = idx
        recall[method] = float(edge[idx].sum()) / n_edge
    size = next(iter(kept.values())).size
    share = "the edge points' share, " if args.ratio is None else ""
    print(f"Each method keeps {size} points ({share}ratio {ratio:.4g}).\nEdge recall: the share of the {n_edge}"
          f" edge points kept; {min(size, n_edge) / n_edge:.3f} at best, {size / n:.3f} for a random subset on"
          " average.\n")
    ranking = sorted(kept, key=lambda m: -recall[m])
    print(f"{'method':<8} {'kept':>6} {'seconds':>8} {'edge recall':>12}")
    for method in ranking:
        note = "" if same[method] is None else f"  same points as {same[method]}"
        print(f"{method:<8} {kept[method].size:>6} {seconds[method]:>8.2f} {recall[method]:>12.3f}{note}")
    for method, first in same.items():
        alike = getattr(hgjax.METHODS[method], "ranks_as", None)
        if alike is not None and alike[0] == first:
            print(f"{method} keeps the points of {first}: {alike[1]}.")
    panels = {"labelled edge points": np.flatnonzero(edge)}
    for method in ranking:
        if same[method] is None:
            names = ", ".join([method] + [m for m in ranking if same[m] == method])
            panels[f"{names}: edge recall {recall[method]:.2f}"] = kept[method]
    if _picture(np.asarray(cloud.points), panels, args.output, args, columns=5,
                title=f"hgjax demo: the {size} points each method keeps (red), best first"):
        print(f"wrote the picture to {os.path.abspath(args.output)}")
    print("next: hgjax resample YOUR_SCAN.ply -o kept.ply --method hkc --ratio 0.2   (or hgjax compare"
          " YOUR_SCAN.ply -o out/ to pick a method)")
