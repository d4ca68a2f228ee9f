#!/usr/bin/env bash
# The checks for a lent NVIDIA GPU, in one command inside a time budget (each stage also has its own limit; a stage
# that no longer fits is skipped and says so):
#   1. `train.py --env`: the backend line and the environment;
#   2. `bench.step_variants`: the step's variants timed side by side at each precision, with kernel profiles;
#   3. the precision trade: DTU 3-view runs of the paper's model and batch on a packed scan, RUNS in order (each
#      METHOD:PRECISION:STEPS[:VARIANT]; FreeNeRF's T = 0.9 x steps, the paper's ratio; VARIANT a step variant
#      of gin bindings, or `fastest`: the fastest such variant stage 2 measured at that precision, else base),
#      each then evaluated on its test views; a run the budget cuts keeps its checkpoints in
#      ckpt_RUN.tar.gz (RUN: METHOD_PRECISION[_VARIANT]), which RESUME_DIR gives back to a later call (it resumes);
#   4. with time left, the numerics tests (TEST_FILES) on the device;
#   5. `lab.gpu_report`: the tables (variants, profiles, precision trade) and a picture (the ground truth of its
#      views from the packed scene, then each run's renders), printed last.
# Usage: bash lab/gpu_check.sh PACKED_SCENE OUT_DIR
#   Environment: BUDGET (seconds for everything, default 540), RUNS (default below), BENCH=0 (skips stage 2),
#   VARIANT_FLAGS (flags of bench.step_variants; by default the fused Pallas layers against the plain step: the
#   XLA flags' variants made no difference on the H100, results/gpu/h100_2026-11-26), EXTRA_BINDINGS (gin
#   bindings for every run, one per line), RESUME_DIR, DTU_SCAN (the scan's Config.dtu_scan when packed, default
#   scan24), PYTHON (default python3), RUN_ROOT (default
#   /tmp/gpu_check_runs), TEST_FILES. PACKED_SCENE from `python -m tools.pack_scene` (docs/running.md).
set -u
scene=$1 out=$2 budget=${BUDGET:-540}
runs=${RUNS:-freenerf:bfloat16:3100:fastest freenerf:default:3100 mipnerf:bfloat16:3100 freenerf:float32:3100}
root=${RUN_ROOT:-/tmp/gpu_check_runs} py=${PYTHON:-python3}
reserve=30  # Seconds kept for the report and for a stopped stage's 20 s of grace.
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
mkdir -p "$out" "$root"
: >"$out/stages.tsv"
stage_dir=$out
source "$(dirname "$0")/stages.sh"  # stage NAME MAX MIN COMMAND...

stage env 60 10 "$py" train.py --env
[ "${BENCH:-1}" = 1 ] && stage step_variants 240 60 "$py" -m bench.step_variants --out_dir "$out" \
  ${VARIANT_FLAGS:---variants base,relu_from_output,pallas,pallas_rows128,pallas_block64}

for spec in $runs; do
  IFS=: read -r method precision steps variant <<<"$spec"
  measured=$out/step_variants.json  # A resuming call without stage 2 picks what the cut call measured.
  [ -f "$measured" ] || measured=${RESUME_DIR:-/nonexistent}/step_variants.json
  if ! picked=$("$py" -m bench.step_variants --bindings "${variant:-base}" --precisions "$precision" \
                 --measured "$measured" 2>&1); then
    echo "== $spec: not run: $picked" && continue
  fi
  mapfile -t chosen <<<"$picked"  # The variant's name, then its gin bindings.
  run=${method}_$precision && [ "${chosen[0]}" != base ] && run+=_${chosen[0]}
  dir=$root/$run
  if [ -f "${RESUME_DIR:-/nonexistent}/ckpt_$run.tar.gz" ]; then
    mkdir -p "$dir" && tar xzf "$RESUME_DIR/ckpt_$run.tar.gz" -C "$dir" && echo "== $run: resuming"
  fi
  bindings=("Config.dataset_loader = 'packed'" "Config.data_dir = '$scene'" "Config.dtu_scan = '${DTU_SCAN:-scan24}'"
            "Config.checkpoint_dir = '$dir'" "Config.precision = '$precision'"
            "Config.max_steps = $steps" "Config.freq_reg_end = $((steps * 9 / 10))"
            "Config.dtu_mask_path = ''" "Config.allow_missing_test_views = True" "Config.compute_lpips = False")
  bindings+=("${chosen[@]:1}")
  [ -n "${EXTRA_BINDINGS:-}" ] && mapfile -t -O ${#bindings[@]} bindings <<<"$EXTRA_BINDINGS"
  stage "train_$run" 420 60 "$py" train.py --gin_configs="configs/$method/dtu3_$method.gin" \
    --gin_bindings "${bindings[@]}" || true
  if grep -q "Trained to step $steps;" "$out/train_$run.log" 2>/dev/null; then
    stage "eval_$run" 120 30 "$py" eval.py --gin_configs="configs/$method/dtu3_$method.gin" \
      --gin_bindings "${bindings[@]}" && preds=$(ls -d "$dir"/test_preds_step_* | tail -n 1) &&
      cp "$preds/metrics.json" "$out/metrics_$run.json" && mkdir -p "$out/test_preds_$run" &&
      for colour in $(ls "$preds"/color_*.png | head -n 3); do  # The picture's views (lab.gpu_report).
        cp "$colour" "${colour/color_/depth_}" "$out/test_preds_$run/"
      done
  elif [ -d "$dir/checkpoints" ]; then
    tar czf "$out/ckpt_$run.tar.gz" -C "$dir" . && echo "== $run: cut short, checkpoints in ckpt_$run.tar.gz"
  fi
done

tests=${TEST_FILES:-tests/test_activations.py tests/test_fused_dense.py tests/test_precision.py tests/test_train_step.py
  tests/test_trig.py}
stage tests 120 45 "$py" -m pytest -q -p no:cacheprovider $tests  # On every core (pytest.ini).
"$py" -c "from lab import gpu_report; gpu_report.write_truth('$scene', '$out')" || true  # The picture's truth.
"$py" -m lab.gpu_report "$out"
