"""Sharding the point axis over several (fake CPU) devices gives the single-device results."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

import hgjax

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = """
import sys, jax, numpy as np
jax.config.update("jax_enable_x64", True)
import hgjax
assert len(jax.devices()) == 4, jax.devices()
p = np.load(sys.argv[1])
out = {name: fn(p) for name, fn in [
    ("hkc", lambda p: hgjax.scores.hkc(p, chunk_size=1024)),
    ("hkf_reference", lambda p: hgjax.scores.hkf(p, variant="reference")),
    ("lhf", lambda p: hgjax.scores.lhf(p, ratio=0.2, chunk_size=512)),
    ("resample_lhf", lambda p: hgjax.resample(p, 0.2, method="lhf").astype(np.float64)),
]}
np.savez(sys.argv[2], **out)
"""


def test_four_fake_devices_match_single_device(tmp_path):
    p = np.random.default_rng(0).random((3000, 3))
    np.save(tmp_path / "p.npy", p)
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=4", JAX_PLATFORMS="cpu")
    subprocess.run([sys.executable, "-c", SCRIPT, str(tmp_path / "p.npy"), str(tmp_path / "out.npz")],
                   check=True, env=env, cwd=ROOT, timeout=600)
    got = np.load(tmp_path / "out.npz")
    np.testing.assert_array_equal(got["hkc"], hgjax.scores.hkc(p))
    np.testing.assert_array_equal(got["hkf_reference"], hgjax.scores.hkf(p, variant="reference"))
    np.testing.assert_array_equal(got["lhf"], hgjax.scores.lhf(p, ratio=0.2))
    np.testing.assert_array_equal(got["resample_lhf"], hgjax.resample(p, 0.2, method="lhf"))
