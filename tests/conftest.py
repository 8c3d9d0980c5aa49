"""The suite's fixtures: a persistent compilation cache per test process and the one Dask cluster (x64 and
no implicit rank promotion: the repository root's conftest)."""

import jax
import numpy as np
import pytest

# Per-dtype tolerances (jax-md style): relative tolerance for kernel-vs-naive agreement.
TOL = {np.dtype(np.float32): 2e-4, np.dtype(np.float64): 1e-10}


@pytest.fixture(params=[np.float32, np.float64], ids=["f32", "f64"])
def dtype(request):
    return np.dtype(request.param)


@pytest.fixture(scope="session", autouse=True)
def compilation_cache(tmp_path_factory):
    """JAX's persistent compilation cache in a temporary folder of this pytest process, for it and
    (JAX_COMPILATION_CACHE_DIR) every process it starts: CLI runs, notebook kernels, Dask workers
    load the streamed kernels (whose shapes do not depend on N) that another compiled.

    Every program is cached, however fast it compiled (as the CLI does). Each pytest-xdist worker
    has its own folder (its basetemp), so two workers never write one cache entry at once."""
    directory = str(tmp_path_factory.getbasetemp() / "jax-cache")
    before = jax.config.jax_compilation_cache_dir, jax.config.jax_persistent_cache_min_compile_time_secs
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("JAX_COMPILATION_CACHE_DIR", directory)
        mp.setenv("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
        jax.config.update("jax_compilation_cache_dir", directory)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
        try:
            yield directory
        finally:
            jax.config.update("jax_compilation_cache_dir", before[0])
            jax.config.update("jax_persistent_cache_min_compile_time_secs", before[1])


@pytest.fixture
def cli_cache(monkeypatch, compilation_cache):
    """The CLI's own cache setting (HGJAX_CACHE_DIR) names the session's cache, never the user's."""
    monkeypatch.setenv("HGJAX_CACHE_DIR", compilation_cache)


@pytest.fixture(scope="session")
def client():
    """A Dask client of one 2-process LocalCluster on 127.0.0.1, started once for the session (its
    workers keep their compiled kernels from one test file to the next)."""
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                                  host="127.0.0.1") as cluster, distributed.Client(cluster) as c:
        yield c


# Per tier (the README's two test commands select one with -m; any other selection takes the full tier's),
# the groups that take longest or hold the longest tests, longest first: the fast tier's from its summed
# durations on a loaded machine (test_cli 135 s, test_gfr 75 s, test_soft 69 s, ...), the full tier's as
# measured on the whole suite before the tiers (the traced-search files, the signal loop, the API and soft
# matrices, the notebooks, ...). pytest-xdist's loadgroup hands groups to whichever worker is free in
# collection order, so these start first and the run ends on short groups (other test files, then the
# doctests of hgjax/): neither worker idles while the other finishes a long one.
LONGEST_GROUPS = {
    "not full": ("tests/test_cli.py", "tests/test_gfr.py", "tests/test_soft.py", "tests/test_cli_scan.py",
                 "tests/test_scores.py", "tests/test_baselines.py", "tests/test_tiles.py", "tests/test_survey.py",
                 "tests/test_resample.py", "tests/test_mss.py", "tests/test_cli_files.py", "tests/test_ragged.py"),
    "full": ("tests/test_traced_jit.py", "tests/test_traced_neighbourhoods.py", "tests/test_traced_graph.py",
             "tests/test_search_jax.py", "tests/test_signals.py", "tests/test_traced_tiles.py", "tests/test_kdtree.py",
             "tests/test_api.py", "tests/test_soft.py", "tests/test_notebooks.py", "tests/test_mss.py",
             "tests/test_cli.py", "tests/test_ragged.py", "tests/test_eval_edges.py", "tests/test_survey.py",
             "tests/test_scores.py", "dask-client", "tests/test_cli_scan.py"),
}


def pytest_configure(config):
    """Groups run in the order of :func:`pytest_collection_modifyitems` (pytest-xdist's
    ``--no-loadscope-reorder``: by default it reorders groups by their number of tests)."""
    if hasattr(config.option, "loadscopereorder"):
        config.option.loadscopereorder = False


def _group(item) -> str:
    return "dask-client" if "client" in getattr(item, "fixturenames", ()) else item.nodeid.split("::")[0]


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist reads the groups and -m deselects
def pytest_collection_modifyitems(config, items):
    """Groups for pytest-xdist's ``--dist loadgroup`` (the README's test command): the tests of one
    file run in one worker (its module fixtures and compiled kernels are made once), and every test
    of the Dask ``client`` runs in one worker, so the suite starts one LocalCluster. Items are put in
    group order: the tier's :data:`LONGEST_GROUPS`, the other test files, the doctests (each stable)."""
    longest = LONGEST_GROUPS.get(config.getoption("markexpr"), LONGEST_GROUPS["full"])
    rank = {group: i for i, group in enumerate(longest)}
    for item in items:
        item.add_marker(pytest.mark.xdist_group(_group(item)))
    doctest = lambda item: not _group(item).startswith(("tests/", "dask-client"))  # noqa: E731
    items.sort(key=lambda item: (rank.get(_group(item), len(rank)), doctest(item)))
