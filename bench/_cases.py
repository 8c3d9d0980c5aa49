"""Case builders shared by tests and benches, so every benchmarked cloud is a tested cloud."""

from __future__ import annotations

import hgjax

HGSP = ("hkc", "hkf", "lhf")
VARIANTS = ("invariant", "reference")
# LHF's reference variant (batched n x n eigh) stalled for minutes on 2000-point clouds on
# this machine (see the report); it runs only with --with-lhf-reference.


def method_runs():
    """(label, method, params) for every registered method; HGSP methods in both variants.

    Looked up at call time, so methods registered later (baselines) are picked up.
    """
    runs = []
    for name in sorted(hgjax.METHODS):
        if name in HGSP:
            runs += [(f"{name}-{v[:3]}", name, {"variant": v}) for v in VARIANTS]
        else:
            runs.append((name, name, {}))
    return runs


def synthetic_clouds(*, n_shapes, n_points, rotate, noise):
    """The synthetic edge set (hgjax.eval.synthetic_set) for one setting."""
    return hgjax.eval.synthetic_set(n_shapes=n_shapes, n_points=n_points, rotate=rotate, noise=noise)
