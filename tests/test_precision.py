"""float64 input without x64: a PrecisionWarning only where float32 loses what the data holds.

The rule (hgjax.working_dtype): warn when float32's rounding at the largest |local coordinate|,
np.spacing(np.float32(m)) / 2, exceeds 2^-10 of the seeded sample's smallest positive
nearest-distinct distance. Every builder and the tiled plan apply it.
"""

import warnings

import jax
import numpy as np
import pytest

import hgjax
import hgjax.tiles
from fixtures import box_union
from hgjax.neighbours import radius_graph, spatial


def georeferenced(n=600, seed=0):
    """Millimetre detail in two patches 1e7 apart, in one frame (float32 rounds by 0.25 at 5e6)."""
    p = np.random.default_rng(seed).random((n, 3)) * 0.5
    p[n // 2:, 0] += 1e7
    return p


def cluster_and_outlier(n=600, seed=0):
    """A dense cluster (spacing about 1e-4) and one point 1e4 away."""
    p = np.random.default_rng(seed).random((n, 3)) * 1e-3
    p[-1] = [1e4, 0.0, 0.0]
    return p


def precision_warnings(fn):
    """The PrecisionWarnings ``fn()`` emits with x64 off (any other warning is an error)."""
    with jax.enable_x64(False), warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("error")
        warnings.simplefilter("always", hgjax.PrecisionWarning)
        fn()
    return [w for w in caught if issubclass(w.category, hgjax.PrecisionWarning)]


BUILDERS = {
    "knn": lambda p: hgjax.knn(p, 8),
    "cube": lambda p: hgjax.cube(p, 0.01),
    "neighbourhoods hkc": lambda p: hgjax.neighbourhoods(p, "hkc"),
    "neighbourhoods gfr": lambda p: hgjax.neighbourhoods(p, "gfr"),
    "resample hkc": lambda p: hgjax.resample(p, 0.2),  # stats resolved by the plan
    "resample ea": lambda p: hgjax.resample(p, 0.2, method="ea"),  # stats gathered for the check only
    "tiles ea": lambda p: hgjax.tiles.resample(p, 0.2, method="ea", tile=0.3),
    "fps jax": lambda p: hgjax.farthest_point_sample(p, 0.2, backend="jax"),
}


def test_the_rule_at_its_boundary():
    with jax.enable_x64(False):
        assert spatial.float32_rounding(1.0) == 2.0 ** -24 == np.spacing(np.float32(1.0)) / 2
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            assert hgjax.working_dtype(np.float64) == np.float32  # nothing known: nothing judged
            assert hgjax.working_dtype(np.float64, extent=1.0, spacing=2.0 ** -14) == np.float32  # rounding = 2^-10 s
        with pytest.warns(hgjax.PrecisionWarning, match="computed in float32"):
            assert hgjax.working_dtype(np.float64, extent=1.0, spacing=2.0 ** -15) == np.float32
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            assert hgjax.working_dtype(np.float64, extent=1.0, spacing=np.inf) == np.float32  # one location

    def never():
        raise AssertionError("the spacing is computed only when float64 is cast to float32")

    with jax.enable_x64(True):
        assert hgjax.working_dtype(np.float64, extent=1e7, spacing=never) == np.float64
    with jax.enable_x64(False):
        assert hgjax.working_dtype(np.float32, extent=1e7, spacing=never) == np.float32


def test_a_box_union_of_20000_points_does_not_warn():
    p = hgjax.eval.box_union_cloud(seed=0, n_points=20_000).points
    assert p.dtype == np.float64
    assert not precision_warnings(lambda: (hgjax.resample(p, 0.2), hgjax.knn(p, 8)))


@pytest.mark.full
@pytest.mark.parametrize("build", list(BUILDERS))
@pytest.mark.parametrize("cloud", [georeferenced, cluster_and_outlier])
def test_detail_float32_loses_warns(cloud, build):
    p = cloud()
    caught = precision_warnings(lambda: BUILDERS[build](p))
    assert caught and "computed in float32" in str(caught[0].message)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        BUILDERS[build](p.astype(np.float32))  # float32 input is never cast
        BUILDERS[build](p)  # x64 (conftest): computed in float64


@pytest.mark.parametrize("build", ["knn", "neighbourhoods gfr", "resample ea", "fps jax"])
def test_a_unit_cloud_does_not_warn(build):
    assert not precision_warnings(lambda: BUILDERS[build](box_union(600, seed=2)))


@pytest.mark.parametrize("duplicates", [False, True])
def test_the_graph_and_the_index_find_the_same_finest_spacing(duplicates):
    p = box_union(1500, seed=3)
    if duplicates:
        p = np.concatenate([p, p[::3]])
    local = spatial.local_frame(p)[0]
    idx, first = radius_graph.graph(local)
    want = spatial.index_spacing(spatial.SpatialIndex(local))
    assert spatial.pair_spacing(local, idx, first) == want
    assert spatial.index_spacing(spatial.SpatialIndex(local, dedupe=True)) == want
