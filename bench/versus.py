"""Two checkouts of hgjax timed side by side on one cloud: old and new, interleaved, same outputs.

Usage:
  python bench/versus.py --old /path/to/other/checkout --calls gfr,gfr:top,floor --out bench/results/x.md
  python bench/versus.py --old ../main --n 200000 --calls pca_ac,ea,fps,fpsample --repeats 3 --out /tmp/v.md

One long-lived worker process per checkout imports ITS hgjax (the checkout first on
``sys.path``) and loads the same cloud, ``hgjax.eval.box_surface(n, seed=0)`` as float32,
saved once by the parent. Every call runs once in each worker as a warm-up (compilation),
then the rounds: each round times every call in the old worker, then in the new one, so a
shared machine's load hits both alike. Reported: medians, new / old, the floor (kNN16 on the
Morton-sorted copy, tree build included, timed in each round in the new worker), each
worker's peak RSS, and whether the two checkouts returned the same indices for every call.

Calls: a method name of ``hgjax.resample(points, 0.2, method=..., key=key(0))``
(``name:top`` adds ``mode="top"``), ``fps`` (``hgjax.farthest_point_sample(points, 0.2)``),
``fpsample`` (the bare ``fpsample.bucket_fps_kdtree_sampling`` call that FPS wraps, on the
same float32 local-frame points) and ``floor``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


def _call(name: str, pts):
    """The function that one timed call runs (imports inside: the worker's hgjax)."""
    import jax
    import numpy as np

    import hgjax

    if name == "floor":
        from scipy.spatial import cKDTree

        sorted_pts = pts[hgjax.spatial_order(pts)]
        return lambda: (cKDTree(sorted_pts).query(sorted_pts, k=16, workers=-1), None)[1]
    if name == "fps":
        return lambda: hgjax.farthest_point_sample(pts, 0.2)
    if name == "fpsample":
        import fpsample

        local = hgjax.spatial.local_frame(pts)[0]
        q = np.ascontiguousarray(np.ldexp(local, -np.frexp(np.abs(local).max())[1]), dtype=np.float32)
        m = -(-pts.shape[0] * 2 // 10)
        return lambda: fpsample.bucket_fps_kdtree_sampling(q, m, start_idx=0)
    method, _, mode = name.partition(":")
    params = {"mode": mode} if mode else {}
    return lambda: hgjax.resample(pts, 0.2, method=method, key=jax.random.key(0), **params)


def worker(cloud: str) -> None:
    """Answer one line per request on stdin: a call name -> JSON {seconds, digest, peak_mb}."""
    import time

    import numpy as np

    sys.path.insert(0, str(HERE))
    import _report

    pts = np.load(cloud)
    calls = {}
    for line in sys.stdin:
        name = line.strip()
        if name not in calls:
            calls[name] = _call(name, pts)
        t = time.perf_counter()
        out = calls[name]()
        seconds = time.perf_counter() - t
        digest = None if out is None else hashlib.sha256(np.ascontiguousarray(np.asarray(out, np.int64))).hexdigest()
        print(json.dumps({"seconds": seconds, "digest": digest, "peak_mb": _report.peak_mb(),
                          "module": sys.modules["hgjax"].__file__}), flush=True)


class _Worker:
    def __init__(self, checkout: Path, cloud: Path):
        env_path = str(checkout.resolve())
        code = (f"import sys; sys.path.insert(0, {env_path!r}); sys.path.insert(1, {str(HERE)!r}); "
                f"import versus; versus.worker({str(cloud)!r})")
        self.proc = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     text=True, cwd=checkout)
        self.checkout = env_path

    def run(self, name: str) -> dict:
        self.proc.stdin.write(name + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"the worker of {self.checkout} stopped on {name!r}")
        return json.loads(line)

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait()


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--old", type=Path, required=True, help="the other checkout (its root)")
    parser.add_argument("--new", type=Path, default=ROOT, help="default: this checkout")
    parser.add_argument("--n", type=int, default=10**6)
    parser.add_argument("--calls", default="gfr,gfr:top")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--note", default="", help="a paragraph to add under the table (e.g. the machine's load)")
    args = parser.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    import numpy as np

    import _report

    names = [c for c in args.calls.split(",") if c != "floor"]
    with tempfile.TemporaryDirectory() as folder:
        cloud = _report.save_box_cloud(args.n, np.float32, folder)
        old, new = _Worker(args.old, cloud), _Worker(args.new, cloud)
        first = {(w, name): w.run(name) for name in names for w in (old, new)}
        for w in (old, new):  # each worker runs its own checkout's hgjax
            assert Path(first[w, names[0]]["module"]).is_relative_to(w.checkout), first[w, names[0]]["module"]
        new.run("floor")
        times = {(w, name): [] for name in names + ["floor"] for w in (old, new)}
        for _ in range(args.repeats):
            for name in names:
                for w in (old, new):
                    times[w, name].append(w.run(name)["seconds"])
            times[new, "floor"].append(new.run("floor")["seconds"])
        peaks = {w: w.run("floor")["peak_mb"] for w in (old, new)}
        old.close()
        new.close()
    floor = statistics.median(times[new, "floor"])
    table = ["| call | old s | new s | new / old | old / floor | new / floor | same indices |",
             "|---|---|---|---|---|---|---|",
             f"| floor: Morton kNN k=16 | | {floor:.3f} | | | 1.00 | |"]
    for name in names:
        o, n_ = statistics.median(times[old, name]), statistics.median(times[new, name])
        same = first[old, name]["digest"] == first[new, name]["digest"]
        table.append(f"| {name} | {o:.3f} | {n_:.3f} | {n_ / o:.2f} | {o / floor:.2f} | {n_ / floor:.2f} | "
                     f"{'yes' if same else 'NO'} |")
    _report.write(args.out, "versus.py", argv, title=f"Old against new at N = {args.n:,} (box surface, float32)",
                  paragraphs=[f"Machine: {_report.machine()}.",
                              f"old = {args.old}, new = {args.new}; medians of {args.repeats} interleaved rounds "
                              f"after a warm-up call of each; peak RSS of the whole worker (all its calls): old "
                              f"{peaks[old]:.0f} MB, new {peaks[new]:.0f} MB."]
                  + ([args.note] if args.note else []), table=table)
    print("\n".join(table))


if __name__ == "__main__":
    main()
