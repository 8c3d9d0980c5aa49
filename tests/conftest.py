"""Strict settings for the whole suite: x64 available, no implicit rank promotion; the CLI's
compilation cache and the one Dask cluster."""

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")

# Per-dtype tolerances (jax-md style): relative tolerance for kernel-vs-naive agreement.
TOL = {np.dtype(np.float32): 2e-4, np.dtype(np.float64): 1e-10}


@pytest.fixture(params=[np.float32, np.float64], ids=["f32", "f64"])
def dtype(request):
    return np.dtype(request.param)


@pytest.fixture
def cli_cache(monkeypatch, tmp_path_factory):
    """The CLI's compiled kernels go to one temporary cache for the session (never the user's), so
    a kernel that one CLI run (in this process or a subprocess) compiled, the next one loads."""
    monkeypatch.setenv("HGJAX_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "jax-cache"))


@pytest.fixture(scope="session")
def client():
    """A Dask client of one 2-process LocalCluster on 127.0.0.1, started once for the session (its
    workers keep their compiled kernels from one test file to the next)."""
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                                  host="127.0.0.1") as cluster, distributed.Client(cluster) as c:
        yield c
