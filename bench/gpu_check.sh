#!/usr/bin/env bash
# The device checks of issue 45 on a lent GPU, all set-up included (under 8 minutes): install hgjax
# with JAX's CUDA plugin, confirm the device, check the traced search against the host on the GPU,
# then time it at 1e5 and 1e6 (bench/results/device_search_gpu.md).
set -euo pipefail
cd "$(dirname "$0")/.."
python -m pip install --quiet "jax[cuda12]" ".[test]"
python -c "import jax; d = jax.devices()[0]; print(d.platform, d.device_kind); assert d.platform == 'gpu'"
python -P -m pytest -q -p no:cacheprovider tests/test_traced_neighbourhoods.py tests/test_search_jax.py
python bench/device_search.py --sizes 100000,1000000 --repeats 3 --out bench/results/device_search_gpu.md
