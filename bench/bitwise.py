"""Bitwise fingerprint of every method's kept indices and scores, to compare two checkouts.

Usage (each checkout on PYTHONPATH in turn, then compare):
  PYTHONPATH=OLD python bench/bitwise.py fingerprint old.npz --dask
  PYTHONPATH=NEW python bench/bitwise.py fingerprint new.npz --dask
  python bench/bitwise.py compare old.npz new.npz

Three clouds (the box union of 3,000 points, the same rounded to 1/50 of a unit: ties and
duplicates, and a float32 box union of 2,500), every registered variant: the kept indices of
``hgjax.resample``, every score (``return_scores``), tiles of 0.5 and 1.5 and, with ``--dask``,
tiles of 1.0 on a 2-worker LocalCluster; an error is recorded by its message.
"""

from __future__ import annotations

import argparse

import numpy as np

KEYED = ("uniform", "gfr")
VARIANTS = [("ea", {}), ("mss", {}), ("lhf", {}), ("hkc", {}), ("hkf", {}), ("uniform", {}), ("gfr", {}),
            ("gfr", {"mode": "top"}), ("voxel", {}), ("fps", {}), ("pca_ac", {}), ("hkc", {"variant": "reference"}),
            ("hkf", {"variant": "reference"}), ("gfr", {"variant": "reference"}),
            ("lhf", {"variant": "reference", "lengths": (4, 8)}), ("pca_ac", {"variant": "reference"})]


def _clouds():
    import hgjax

    p = hgjax.eval.box_union_cloud(seed=1, n_points=3000).points
    yield "smooth", p
    yield "rounded", np.round(p * 50) / 50
    yield "f32", hgjax.eval.box_union_cloud(seed=2, n_points=2500).points.astype(np.float32)


def _recorded(out: dict, tag: str, run) -> None:
    try:
        out[tag] = np.asarray(run())
    except Exception as err:  # noqa: BLE001 (an error is part of the fingerprint)
        out[tag + "_err"] = np.array(f"{type(err).__name__}: {err}")


def fingerprint(path: str, dask: bool) -> None:
    import warnings

    import jax

    import hgjax
    from hgjax import tiles

    warnings.simplefilter("ignore", hgjax.PrecisionWarning)
    client = None
    if dask:
        from distributed import Client, LocalCluster
        client = Client(LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None))
    out = {}
    for cloud, p in _clouds():
        for method, params in VARIANTS:
            tag = f"{cloud}/{method}/{'-'.join(f'{k}={v}' for k, v in params.items())}"
            kw = dict(params, **({"key": jax.random.key(3 + KEYED.index(method))} if method in KEYED else {}))
            _recorded(out, tag + "/one", lambda: hgjax.resample(p, 0.2, method=method, **kw))
            _recorded(out, tag + "/scores", lambda: _scores(tiles.resample(p, 0.2, method=method, return_scores=True, **kw)))
            for tile in (0.5, 1.5):
                _recorded(out, tag + f"/tile{tile}", lambda: tiles.resample(p, 0.2, method=method, tile=tile, **kw))
            if client is not None:
                _recorded(out, tag + "/dask", lambda: tiles.resample(p, 0.2, method=method, tile=1.0, client=client, **kw))
    np.savez(path, **out)
    print(f"{len(out)} entries -> {path}")
    if client is not None:
        client.close()


def _scores(run):
    return np.array([]) if run[1] is None else run[1]


def compare(a_path: str, b_path: str) -> None:
    a, b = np.load(a_path), np.load(b_path)
    common = sorted(set(a.files) & set(b.files))
    differ = [k for k in common if not (a[k].dtype == b[k].dtype and np.array_equal(a[k], b[k]))]
    print(f"only in {a_path}: {sorted(set(a.files) - set(b.files))}")
    print(f"only in {b_path}: {sorted(set(b.files) - set(a.files))}")
    print(f"{len(common)} common entries, {len(common) - len(differ)} bitwise identical; differ: {differ}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True)
    f = sub.add_parser("fingerprint")
    f.add_argument("out")
    f.add_argument("--dask", action="store_true")
    c = sub.add_parser("compare")
    c.add_argument("a")
    c.add_argument("b")
    args = ap.parse_args()
    if args.command == "fingerprint":
        fingerprint(args.out, args.dask)
    else:
        compare(args.a, args.b)


if __name__ == "__main__":
    main()
