#!/usr/bin/env bash
# The checks to run when an NVIDIA GPU is at hand, in one command (each stage bounded by its own time limit):
#   1. `train.py --env`: the backend line and the environment;
#   2. `bench.device`: steps and rendering of mip-NeRF and FreeNeRF at each Config.precision, batch 4096;
#   3. a short DTU 3-view run of METHOD (default freenerf; or mipnerf, regnerf) on a packed scan (the paper's model
#      and batch, Config.precision 'default', the schedule shortened to what fits TRAIN_SECONDS at the step rate
#      stage 2 measured, or to STEPS steps, which skips stage 2), then `eval.py` on its test views;
#   4. the numerics and train-step tests on the GPU.
# Usage: bash bench/gpu_check.sh PACKED_SCENE OUT_DIR [TRAIN_SECONDS]
#   Environment: DTU_SCAN (the scan's Config.dtu_scan when packed, default scan24), PYTHON (default python3),
#   RUN_DIR (the training run, default /tmp/gpu_check_run), and for a quick try on a CPU BENCH_FLAGS (e.g. '--tiny
#   --batch_size 64'), EXTRA_BINDINGS (gin bindings, one per line) and TEST_FILES (stage 4's test files).
#   PACKED_SCENE from `python -m tools.pack_scene` (docs/running.md); OUT_DIR gets the logs, bench_device.json,
#   metrics.json and a picture of three test views (colour over depth).
set -u
scene=$1 out=$2 train_seconds=${3:-150}
run=${RUN_DIR:-/tmp/gpu_check_run} py=${PYTHON:-python3}
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
mkdir -p "$out"

stage() {  # stage NAME SECONDS COMMAND...: runs COMMAND under a time limit, its output in OUT_DIR/NAME.log.
  local name=$1 limit=$2
  shift 2
  echo "== $name: $(date +%T), limit ${limit}s"
  timeout -s TERM -k 20 "$limit" "$@" >"$out/$name.log" 2>&1
  echo "== $name: status $?"
  tail -n 30 "$out/$name.log"
}

stage env 60 "$py" train.py --env
method=${METHOD:-freenerf} steps=${STEPS:-}
if [ -z "$steps" ]; then
  stage bench 180 "$py" -m bench.device --methods mipnerf,freenerf --repeats 3 --out "$out/bench_device.json" \
    ${BENCH_FLAGS:-}
  steps=$("$py" - "$out/bench_device.json" "$train_seconds" <<'EOF'
import json, sys
try:
  step = json.load(open(sys.argv[1]))['results']['default']['methods']['freenerf']['step_seconds']
except (OSError, KeyError, ValueError):
  step = 0.2  # No benchmark result: a guess, and SIGTERM at the limit saves a checkpoint anyway.
print(max(200, min(20000, int(float(sys.argv[2]) / step / 100) * 100)))
EOF
  )
fi
echo "== training $method for $steps steps (FreeNeRF's T = 0.9 x steps)"
bindings=("Config.dataset_loader = 'packed'" "Config.data_dir = '$scene'" "Config.dtu_scan = '${DTU_SCAN:-scan24}'"
          "Config.checkpoint_dir = '$run'"
          "Config.max_steps = $steps" "Config.freq_reg_end = $((steps * 9 / 10))" "Config.precision = 'default'"
          "Config.dtu_mask_path = ''" "Config.allow_missing_test_views = True" "Config.compute_lpips = False")
[ -n "${EXTRA_BINDINGS:-}" ] && mapfile -t -O ${#bindings[@]} bindings <<<"$EXTRA_BINDINGS"
stage train $((train_seconds + 120)) "$py" train.py --gin_configs="configs/$method/dtu3_$method.gin" \
  --gin_bindings "${bindings[@]}"
stage eval 120 "$py" eval.py --gin_configs="configs/$method/dtu3_$method.gin" --gin_bindings "${bindings[@]}"
"$py" - "$run" "$out" <<'EOF'
import glob, os, shutil, sys
import numpy as np
from PIL import Image
run, out = sys.argv[1:]
preds = sorted(glob.glob(os.path.join(run, 'test_preds_step_*')))
if preds:
  shutil.copy(os.path.join(preds[-1], 'metrics.json'), out)
  colour = sorted(glob.glob(os.path.join(preds[-1], 'color_*.png')))[:3]
  if colour:
    rows = [np.concatenate([np.asarray(Image.open(p.replace('color_', kind)).convert('RGB')) for p in colour], 1)
            for kind in ('color_', 'depth_')]
    Image.fromarray(np.concatenate(rows, 0)).save(os.path.join(out, 'test_views.png'))
  print('outputs:', sorted(os.listdir(preds[-1]))[:8])
EOF
tests=${TEST_FILES:-tests/test_encoding.py tests/test_gaussians.py tests/test_trig.py tests/test_volume_render.py
  tests/test_sampling.py tests/test_losses.py tests/test_rays.py tests/test_freq_schedule.py tests/test_precision.py
  tests/test_models.py tests/test_nerf.py tests/test_optim.py tests/test_train_step.py tests/test_regnerf.py
  tests/test_environment.py tests/test_metrics.py tests/test_stuck.py}
parallel=$("$py" -c 'import xdist' 2>/dev/null && echo '-n 8')  # pytest-xdist where installed.
stage tests 150 "$py" -m pytest -q $parallel -p no:cacheprovider $tests
