"""Tiles as Dask tasks on a 2-process LocalCluster: the same indices as one process, worker faults survived."""

import os
import signal
import threading
import time

import jax
import numpy as np
import pytest

import hgjax
from hgjax import tiles
from hgjax.engine import _grid, _runners

pytestmark = pytest.mark.full

distributed = pytest.importorskip("distributed")

CASES = [("ea", {}), ("mss", {}), ("lhf", {}), ("hkc", {}), ("gfr", {"key": jax.random.key(1)}), ("gfr", {"mode": "top"}),
         ("uniform", {"key": jax.random.key(2)}), ("voxel", {})]


@pytest.fixture(scope="module")
def clouds():
    smooth = hgjax.eval.box_union_cloud(seed=3, n_points=2500).points
    return {"smooth": smooth, "rounded": np.round(smooth * 50) / 50}


@pytest.mark.parametrize("method,params", CASES, ids=[f"{m}-{p.get('mode', 'default')}" for m, p in CASES])
@pytest.mark.parametrize("which", ["smooth", "rounded"])
def test_dask_tiles_equal_one_process(client, clouds, method, params, which):
    p = clouds[which]
    want = hgjax.resample(p, 0.2, method=method, **params)
    got = tiles.resample(p, 0.2, method=method, tile=1.5, client=client, **params)
    np.testing.assert_array_equal(got, want)


def test_a_memmap_travels_as_its_file(client, tmp_path):
    p = hgjax.eval.box_union_cloud(seed=4, n_points=2500).points.astype(np.float32)
    np.save(tmp_path / "c.npy", p)
    disk = np.load(tmp_path / "c.npy", mmap_mode="r")
    np.testing.assert_array_equal(tiles.resample(disk, 0.2, method="ea", tile=1.5, client=client),
                                  hgjax.resample(p, 0.2, method="ea"))


def test_tiles_are_spread_over_the_workers_largest_first(client, clouds):
    """Every worker runs tiles, the largest first to the least loaded (the scheduler alone ran them all
    where the cloud was held); the placement is stable and the indices those of one process."""
    p = clouds["smooth"]
    plan, cloud = tiles.plan(p, 0.2, method="ea", tile=1.0)
    runner = _runners.Dask(cloud, client, 16)
    cells = runner.cloud.occupied()
    where = runner.placed(cells)
    assert set(where.values()) == set(client.ncores()) and where == runner.placed(cells[::-1])
    load = {w: sum(runner.cloud.core_size(c) for c in cells if where[c] == w) for w in client.ncores()}
    assert max(load.values()) - min(load.values()) <= max(map(runner.cloud.core_size, cells))
    parts = runner.tiles(_grid.tile_scores, plan)
    distributed.wait(parts)
    ran = client.who_has(parts)
    assert {ran[f.key][0] for f in parts} == set(client.ncores())
    assert all(ran[f.key] == (where[c],) for f, c in zip(parts, cells))
    np.testing.assert_array_equal(tiles.resample(p, 0.2, method="ea", tile=1.0, client=client),
                                  hgjax.resample(p, 0.2, method="ea"))


def test_a_worker_killed_mid_run_changes_nothing(client):
    p = hgjax.eval.box_union_cloud(seed=5, n_points=6000).points
    want = hgjax.resample(p, 0.2, method="hkc")
    pids = client.run(os.getpid)
    out = {}
    run = threading.Thread(target=lambda: out.update(idx=tiles.resample(p, 0.2, method="hkc", tile=0.8, client=client)))
    run.start()
    deadline = time.monotonic() + 60
    while not any(client.processing().values()) and time.monotonic() < deadline:
        time.sleep(0.01)
    os.kill(next(iter(pids.values())), signal.SIGKILL)
    run.join(timeout=300)
    np.testing.assert_array_equal(out["idx"], want)
    client.wait_for_workers(2, timeout=60)  # the nanny restarted it


def test_a_tile_beyond_the_workers_memory_names_itself_and_its_memory():
    """A real out-of-memory death: workers limited to 500 MiB (a worker holds about 350 MiB with JAX and
    the cloud) and a tile of 1,000,000 core points (about 490 MiB more, by the message's estimate). The
    nanny kills each worker that runs it, Dask retries it once (``allowed-failures``), then gives up; the
    error names the tile, the estimate and the limit. Pausing and spilling are off, so a worker near its
    limit cannot leave the cluster waiting. The large tile can also pass between two of the nanny's memory
    samples and leave its worker to die during a later small task; the error then names the small tile
    and the large one with its estimate (the next test), so the match below holds either way."""
    dask = pytest.importorskip("dask")
    rng = np.random.default_rng(0)
    xy = np.concatenate([rng.uniform(0, 1, (1_000_000, 2)), rng.uniform(0, 2, (4000, 2))])
    p = np.concatenate([xy, rng.normal(0, 0.01, (xy.shape[0], 1))], axis=1)
    memory = {f"distributed.worker.memory.{k}": False for k in ("target", "spill", "pause")}
    with dask.config.set({"distributed.scheduler.allowed-failures": 1, **memory}), \
            distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, memory_limit="500MiB",
                                     dashboard_address=":0", host="127.0.0.1") as cluster, \
            distributed.Client(cluster) as client:
        _, cloud = tiles.plan(p, 0.2, method="ea", tile=1.0)
        assert len(cloud.occupied()) == 4 and cloud.core_size((0, 0, 0)) > 1_000_000
        with pytest.raises(RuntimeError, match=r"tile \(0, 0, 0\).* needs about \d+\.\d MiB .*an estimate: 100\d{4}"
                                                r" core points x K=16 .*memory limit: 500 MiB") as err:
            tiles.resample(p, 0.2, method="ea", tile=1.0, client=client)
    assert isinstance(err.value.__cause__, distributed.KilledWorker)


def test_a_worker_dead_in_a_small_task_names_the_largest_tile_too():
    """The message when the blamed task's tile is small: both tiles with their estimates, the limit."""
    rng = np.random.default_rng(1)
    p = np.concatenate([rng.uniform(0, 1, (3000, 3)) * [1, 1, 0.01], rng.uniform(0, 2, (400, 3)) * [1, 1, 0.01]])
    _, cloud = tiles.plan(p, 0.2, method="ea", tile=1.0)
    small, large = sorted(cloud.occupied(), key=cloud.core_size)[::len(cloud.occupied()) - 1]
    dask = object.__new__(_runners.Dask)
    dask.cloud, dask.k, dask.cells = cloud, 16, {"a": small, "b": large}
    message = dask.killed("a", 2**29)
    assert message.startswith(f"Dask workers died running tile {small} (task 'a'): it needs about 0.0 MiB")
    assert f"the largest tile {large} needs about {cloud.core_size(large) * 16 * 32 / 2**20:.1f} MiB" in message
    assert f"an estimate: {cloud.core_size(large)} core points x K=16" in message
    assert message.endswith("the workers' memory limit: 512 MiB; give each worker more memory or pass a smaller tile")
    assert "largest" not in dask.killed("b", None)
