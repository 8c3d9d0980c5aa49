#!/usr/bin/env bash
# The device checks of issue 45 on a lent GPU, all set-up included (under 8 minutes). The GPU
# machine has JAX with its CUDA plugin, NumPy, SciPy and pytest but no network: hgjax runs from
# this tree (PYTHONPATH) and trimesh comes as a wheel carried in .whl/ (fetched beforehand with
# `pip download --no-deps -d .whl trimesh`). Confirms the device, checks the traced search
# against the host there, then times it (bench/results/device_search_gpu.md, or $OUT/ when set).
#   bash bench/gpu_check.sh [SIZES]   (default 100000,1000000)
set -euo pipefail
cd "$(dirname "$0")/.."
if [ -d .whl ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl/*.whl
  export PYTHONPATH="/tmp/site:${PYTHONPATH:-}"
fi
export PYTHONPATH="$PWD:${PYTHONPATH:-}" PYTHONUNBUFFERED=1
python3 -c "import jax; d = jax.devices()[0]; print(jax.__version__, d.platform, d.device_kind); assert d.platform == 'gpu'"
out="${OUT:-bench/results}"
timeout 120 python3 -P -m pytest -q -x -p no:cacheprovider tests/test_traced_neighbourhoods.py 2>&1 | tail -5 || true
python3 bench/device_search.py --sizes "${1:-100000,1000000}" --repeats 3 --out "$out/device_search_gpu.md"
