"""Real-data robustness of every default score: duplicates, far outliers, mixed densities,
georeferenced offsets."""

import warnings

import jax
import numpy as np
import pytest

import hgjax
from fixtures import box_union, grid

DEFAULTS = ["hkc", "hkf", "lhf", "ea", "gfr"]
SELECT = {"gfr": {"mode": "top"}}


def _locations(points, idx):
    return {tuple(x) for x in np.asarray(points)[idx]}


def _overlap(a, b):
    return len(a & b) / len(b)


@pytest.fixture(scope="module")
def base():
    p = box_union(4000)
    return p, {m: _locations(p, hgjax.resample(p, 0.2, method=m, **SELECT.get(m, {}))) for m in DEFAULTS}


@pytest.mark.full
@pytest.mark.parametrize("method", DEFAULTS)
def test_duplicated_points_keep_the_same_locations(base, method):
    p, kept = base
    dup = np.concatenate([p, p[::-1]])
    got = _locations(dup, hgjax.resample(dup, 0.2, method=method, **SELECT.get(method, {})))
    assert _overlap(got, kept[method]) >= 0.95


@pytest.mark.parametrize("method", DEFAULTS)
def test_a_far_outlier_changes_nothing_else(base, method):
    p, kept = base
    out = np.concatenate([p, [[1e6, -1e6, 1e6]]])
    idx = hgjax.resample(out, 0.2, method=method, **SELECT.get(method, {}))
    got = _locations(out, idx[idx < len(p)][: len(kept[method])])
    assert _overlap(got, kept[method]) >= 0.95


def _mixed_density():
    """A 40 x 40 grid plane of spacing 1 with a 100 x 100 patch of spacing 0.01 beside it:
    area densities differ 1e4-fold."""
    sparse = grid((40, 40, 1))
    dense = grid((100, 100, 1), 0.01) + [40.5, 10.0, 0.0]
    return np.concatenate([sparse, dense])


@pytest.mark.full
@pytest.mark.parametrize("method", DEFAULTS)
def test_mixed_densities_give_finite_scores_without_errors(method):
    p = _mixed_density()
    nb = hgjax.neighbourhoods(p, method)
    s = np.asarray(hgjax.score(nb, method))
    assert s.shape[0] == len(p) and not np.isnan(s).any()
    assert nb.idx.shape[1] <= 256  # bounded neighbourhoods: no blow-up in the dense patch


@pytest.mark.full
@pytest.mark.parametrize("x64", [True, False], ids=["x64", "x32"])
@pytest.mark.parametrize("method", ["hkc", "lhf", "ea", "gfr", "fps"])
def test_georeferenced_offsets_keep_the_same_points(method, x64):
    p = box_union(3000, seed=1) * 20.0  # metres, spacing about 0.05
    utm = p + np.array([512_345.678, 4_123_456.789, 87.5])
    kw = SELECT.get(method, {})
    with jax.enable_x64(x64), warnings.catch_warnings():
        warnings.simplefilter("ignore", hgjax.PrecisionWarning)
        a = hgjax.resample(p, 0.2, method=method, **kw)
        b = hgjax.resample(utm, 0.2, method=method, **kw)
    assert len(set(a.tolist()) & set(b.tolist())) / len(a) >= 0.99
