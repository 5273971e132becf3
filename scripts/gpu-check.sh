#!/usr/bin/env bash
# The GPU check (issue 40), start to end in a few minutes on a machine with one NVIDIA GPU, from the
# repository root of a working tree; results under $OUT (default gpu-check/):
#   nvidia-smi.txt   the GPU and its driver
#   tests.log        the parity tests: the CUDA tests (tests/envs/test_cuda.py: a GPU row is the CPU row,
#                    no host sync inside a step, the CUDA-graph and compiled steps, the device trainer
#                    learning table1-train on 3 seeds) and the CPU torch-backend tests beside them
#   perf-gpu.json/md `overtakezoo perf --device cuda --compile`: env-steps/s at each N in float64,
#                    float32, CUDA graph and torch.compile + graph, beside the numpy core; launches per step
#   train.log        `overtakezoo train ppo-numpy --device cuda` on table1-train (3 seeds, table1 results)
#                    and on the core-train mixture (wall time, env-steps/s from the cards)
#   runs.tgz         those runs' cards and logs
# Without a package index: run scripts/gpu-wheels.sh here first and carry .whl with the tree.
# Each part's failure is logged and the next part still runs; the exit status is the tests'.
set -uo pipefail
OUT=${OUT:-gpu-check}
PY=${PYTHON:-python3}
mkdir -p "$OUT"
SITE=$(mktemp -d)
if compgen -G ".whl/*.whl" > /dev/null; then
    $PY -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target "$SITE" .whl/*.whl || exit 1
fi
# The package from this tree without building it: overtakezoo.{envs,zoo,benchmark} are the root's folders.
mkdir -p "$SITE/overtakezoo"
for layer in envs zoo benchmark; do ln -sfn "$PWD/$layer" "$SITE/overtakezoo/$layer"; done
export PYTHONPATH="$SITE${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
oz() { $PY -c 'import sys; from overtakezoo.benchmark.cli import main; sys.exit(main())' "$@"; }

nvidia-smi > "$OUT/nvidia-smi.txt" 2>&1
$PY -c 'import torch; print("torch", torch.__version__, "cuda", torch.version.cuda, torch.cuda.get_device_name())' \
    | tee -a "$OUT/nvidia-smi.txt"

$PY -m pytest -q -p no:cacheprovider tests/envs/test_cuda.py tests/envs/test_sync_free.py tests/envs/test_backend.py \
    tests/benchmark/test_device.py tests/zoo/test_devppo.py 2>&1 | tee "$OUT/tests.log"
status=${PIPESTATUS[0]}

oz perf --device cuda --compile --sizes 4096 65536 1048576 4194304 --seconds 1 --repeats 3 --out "$OUT/perf-gpu" \
    2>&1 | tail -40

runs=$(mktemp -d)
{
    for seed in 0 1 2; do
        oz train ppo-numpy --suite table1-train --device cuda --seed "$seed" --out "$runs/table1-s$seed" --no-progress
    done
    # core-train as perf's time-to-zoo-quality trains it (4096 rows, selection every 8 iterations), 60 iterations
    oz train ppo-numpy --suite core-train --device cuda --seed 0 --out "$runs/core-s0" --no-progress \
        --steps $((60 * 4096 * 4)) --set env.num_envs=4096 --set train.select_every=8
    $PY - "$runs" <<'PYEOF'
import json, pathlib, sys
for card in sorted(pathlib.Path(sys.argv[1]).glob("*/ppo-numpy.json")):
    c = json.loads(card.read_text())
    env_steps = c["steps"] * c["action_repeat"]
    res = c.get("results", {}).get("table1")
    print(f"{card.parent.name}: {c['training']['trainer']}, {c['steps']} decisions = {env_steps} env-steps "
          f"in {c['wall_time_s']:.2f} s ({env_steps / c['wall_time_s']:,.0f} env-steps/s; cpu_s {c['training']['cpu_s']})"
          + (f"; table1 success {100 * res['success_rate']:.1f} %" if res else ""))
PYEOF
} 2>&1 | tee "$OUT/train.log"
tar czf "$OUT/runs.tgz" -C "$runs" . 2>/dev/null
exit "$status"
