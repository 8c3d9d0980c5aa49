#!/usr/bin/env bash
# The device checks on a lent GPU, all set-up included (under 8 minutes). The GPU
# machine has JAX with its CUDA plugin, NumPy, SciPy and pytest but no network: hgjax runs from
# this tree (PYTHONPATH) and trimesh comes as a wheel carried in .whl/ (fetched beforehand with
# `pip download --no-deps -d .whl trimesh`). Confirms the device, times the traced search beside
# the host and checks its neighbour sets and kept points (bench/results/device_search_gpu.md, or
# $OUT/ when set), runs the jitted trial with no sizes passed (traced_jit_gpu.md) and a learning step (32 moving clouds
# x 4,096 points, value_and_grad: learning_step_gpu.md), then the
# traced-search tests there for what time is left.
#   bash bench/gpu_check.sh [SIZES [METHODS]]   (default 100000,1000000 and every method that takes search)
set -euo pipefail
cd "$(dirname "$0")/.."
if [ -d .whl ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl/*.whl
  export PYTHONPATH="/tmp/site:${PYTHONPATH:-}"
fi
export PYTHONPATH="$PWD:${PYTHONPATH:-}" PYTHONUNBUFFERED=1
python3 -c "import jax; d = jax.devices()[0]; print(jax.__version__, d.platform, d.device_kind); assert d.platform == 'gpu'"
out="${OUT:-bench/results}"
python3 bench/device_search.py --sizes "${1:-100000,1000000}" ${2:+--methods "$2"} --repeats 3 \
  --out "$out/device_search_gpu.md"
python3 bench/traced_jit.py --n 20000 --out "$out/traced_jit_gpu.md"
python3 bench/learning_step.py --batch 32 --n 4096 --methods ea,lhf,mss --repeats 5 --out "$out/learning_step_gpu.md"
timeout 120 python3 -P -m pytest -q -x -p no:cacheprovider tests/test_traced_tiles.py 2>&1 | tail -3 || true
