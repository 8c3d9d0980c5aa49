"""Sharding the point axis over several (fake CPU) devices gives the single-device results."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import hgjax

pytestmark = pytest.mark.full

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = """
import sys, jax, numpy as np
jax.config.update("jax_enable_x64", True)
import hgjax
from hgjax import _stream
assert len(jax.devices()) == 4, jax.devices()
assert _stream.chunk_rows() == 4 * _stream.CHUNK_BLOCKS * _stream.BLOCK  # a chunk per device
p = np.load(sys.argv[1])
out = {name: np.asarray(fn(p)) for name, fn in [
    ("hkc", lambda p: hgjax.score(hgjax.neighbourhoods(p, "hkc"), "hkc", chunk_size=1024)),
    ("hkf_reference", lambda p: hgjax.score(hgjax.neighbourhoods(p, "hkf", variant="reference"), "hkf",
                                            variant="reference")),
    ("lhf", lambda p: hgjax.score(hgjax.neighbourhoods(p, "lhf"), "lhf", chunk_size=512)),
    ("ea", lambda p: hgjax.score(hgjax.neighbourhoods(p, "ea"), "ea")),
    ("resample_lhf", lambda p: hgjax.resample(p, 0.2, method="lhf").astype(np.float64)),
    ("resample_hkc", lambda p: hgjax.resample(p, 0.2, method="hkc").astype(np.float64)),
]}
np.savez(sys.argv[2], **out)
"""


def scores_of(points, method, **params):
    return np.asarray(hgjax.score(hgjax.neighbourhoods(points, method, **params), method, **params))


def test_four_fake_devices_match_single_device(tmp_path):
    p = np.random.default_rng(0).random((3000, 3))
    np.save(tmp_path / "p.npy", p)
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=4", JAX_PLATFORMS="cpu")
    subprocess.run([sys.executable, "-c", SCRIPT, str(tmp_path / "p.npy"), str(tmp_path / "out.npz")],
                   check=True, env=env, cwd=ROOT, timeout=600)
    got = np.load(tmp_path / "out.npz")
    np.testing.assert_array_equal(got["hkc"], scores_of(p, "hkc"))
    np.testing.assert_array_equal(got["hkf_reference"], scores_of(p, "hkf", variant="reference"))
    np.testing.assert_array_equal(got["lhf"], scores_of(p, "lhf"))
    np.testing.assert_array_equal(got["ea"], scores_of(p, "ea"))
    np.testing.assert_array_equal(got["resample_lhf"], hgjax.resample(p, 0.2, method="lhf"))
    np.testing.assert_array_equal(got["resample_hkc"], hgjax.resample(p, 0.2, method="hkc"))
