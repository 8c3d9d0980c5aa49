"""Case builders shared by tests and benches, so every benchmarked cloud is a tested cloud."""

from __future__ import annotations

import hgjax

HGSP = ("hkc", "hkf", "lhf")
VARIANTS = ("invariant", "reference")
# The methods of the paper's Table 1, in its order.
PAPER_METHODS = ("hkc", "hkf", "lhf", "gfr", "ea", "pca_ac")
# Methods with a ``variant="reference"`` (REFERENCE.md); EA and PCA-AC have one definition.
REFERENCE_VARIANT = ("hkc", "hkf", "lhf", "gfr")


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


def reference_params(method):
    """The paper's reference settings of a Table 1 method: its reference variant, if any."""
    return {"variant": "reference"} if method in REFERENCE_VARIANT else {}


def table1_runs(*, settings):
    """(label, method, params) of the Table 1 methods in ``"reference"`` or ``"default"`` settings.

    Default settings pass no parameter at all, so the rows follow the library's defaults.
    """
    if settings == "reference":
        return [(f"{m}-ref" if reference_params(m) else m, m, reference_params(m)) for m in PAPER_METHODS]
    return [(f"{m} (default)", m, {}) for m in PAPER_METHODS]


def synthetic_clouds(*, n_shapes, n_points, rotate, noise, regime="random"):
    """The synthetic edge set (hgjax.eval.synthetic_set) for one setting."""
    return hgjax.eval.synthetic_set(n_shapes=n_shapes, n_points=n_points, rotate=rotate, noise=noise, regime=regime)
