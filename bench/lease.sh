#!/usr/bin/env bash
# One GPU window moves the ledger of paper-length runs forward (bench/ledger.toml; docs/benchmarks.md, "GPU windows:
# the ledger"). The one command a window runs, from the repository's root, `bash bench/lease.sh`, carrying .whl and
# .devdata (`python -m bench.prepare_lease` fills them and prints the call). Inside BUDGET seconds, each stage with
# a limit of its own (a stage that no longer fits is skipped and says so; a stopped one gets SIGTERM, on which
# training saves a checkpoint):
#   1. the wheels of .whl installed to /tmp/site; `bench.ledger plan`: the plan, printed;
#   2. on a GPU whose kind has not timed this code's step yet (results/gpu/ledger/timed.json): the step variants
#      (bench.step_variants), RegNeRF's step beside mip-NeRF's (bench.device) and the fused layer's GPU tests, within
#      the ledger's variants_seconds;
#   3. the first unfinished run resumed from its committed checkpoint with its variant (a new run: the fastest
#      correct one timed), trained until the budget with a learning-curve point every curve_every steps; evaluated
#      on every test view once finished, then the next run; each run packed as it ends;
#   4. the window's logs and timings packed. Into $OUT (what comes back, 8 files at most): lease.log,
#      window.tar.gz, run_RUN.tar.gz and eval_RUN.tar.gz per run. `python -m bench.ledger unpack FOLDER` commits them.
# Environment: OUT (required), BUDGET (seconds, default 540), PYTHON (python3), LEASE_WORK (an empty folder for run
# folders and logs, default a new one under /tmp), LEDGER, RESULTS, DATA (bench.ledger's --ledger, --results,
# --data), EVAL_SECONDS (an evaluation's limit, default 180: 13 views take about 20 s on an H100), STOP_AT_STEP (dry
# runs and tests: training stops after this step, as a budget would cut it).
set -u
cd "$(dirname "$0")/.." || exit 2
out=${OUT:?OUT: the folder that comes back from the window} budget=${BUDGET:-540} py=${PYTHON:-python3}
work=${LEASE_WORK:-$(mktemp -d /tmp/lease.XXXXXX)}
reserve=45  # Seconds kept for packing (a run and the window) after the last stage.
# Seconds from a stage's SIGTERM to its SIGKILL: training stopped by the budget finishes its step, the curve point
# in progress (13 views, their render compiled at the first point) and a checkpoint; a checkpoint every
# checkpoint_every steps bounds what a SIGKILL loses.
grace=40
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false JAX_COMPILATION_CACHE_DIR=$work/jax_cache
ledger=(--ledger "${LEDGER:-bench/ledger.toml}" --results "${RESULTS:-results/gpu/ledger}" --data "${DATA:-.devdata}")
mkdir -p "$out" "$work/logs" || exit 2
[ -z "$(ls -A "$work/logs")" ] || { echo "LEASE_WORK $work is not new; expected an empty folder"; exit 2; }
exec > >(tee -a "$out/lease.log") 2>&1
: >"$work/logs/stages.tsv"
stage_dir=$work/logs
source bench/stages.sh  # stage NAME MAX MIN COMMAND...

if compgen -G '.whl/*.whl' >/dev/null; then  # The packages the GPU image lacks (bench.prepare_lease).
  timeout 120 "$py" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site \
    .whl/*.whl && export PYTHONPATH=/tmp/site${PYTHONPATH:+:$PYTHONPATH}
fi
command -v nvidia-smi >/dev/null && timeout 20 nvidia-smi --format=csv \
  --query-gpu=name,memory.total,driver_version,clocks.sm,clocks.mem,temperature.gpu,power.draw >"$work/nvidia_smi.csv"
stage plan 90 10 "$py" -m bench.ledger plan --work "$work" --budget "$budget" "${ledger[@]}" &&
  source "$work/plan.env"

if [ "${TIME_VARIANTS:-0}" = 1 ]; then  # Each its own share of VARIANTS_SECONDS; a stage cut keeps what it wrote.
  mkdir -p "$work/variants"
  stage step_variants $((VARIANTS_SECONDS * 3 / 5)) 60 "$py" -m bench.step_variants --out_dir "$work/variants" \
    --precisions bfloat16 --profile_steps 2 --variants "$VARIANTS" --build_seconds $((VARIANTS_SECONDS * 3 / 10))
  stage regnerf_step $((VARIANTS_SECONDS * 2 / 9)) 30 "$py" -m bench.device --methods mipnerf,regnerf \
    --precisions bfloat16 --repeats 3 --render_rays 4096 --out "$work/variants/bench_device.json"
  stage fused_tests $((VARIANTS_SECONDS * 8 / 45)) 20 "$py" -m pytest -q -p no:cacheprovider tests/test_fused_dense.py
  cp "$work/logs/"{step_variants,regnerf_step,fused_tests}.log "$work/variants/" 2>/dev/null
fi

while stage next 90 10 "$py" -m bench.ledger next --work "$work" "${ledger[@]}"; do
  source "$work/next.env"  # RUN, ACTION, STEPS
  mapfile -t args <"$work/$RUN.args"  # The gin file, then the bindings.
  stop=() && [ -n "${STOP_AT_STEP:-}" ] && stop=(--stop_at_step "$STOP_AT_STEP")
  log=train_$RUN
  if [ "$ACTION" = train ]; then
    stage "$log" 100000 60 "$py" train.py --gin_configs="${args[0]}" --gin_bindings "${args[@]:1}" "${stop[@]}"
    status=$?  # 124: the budget cut it (a checkpoint saved); anything else but 0 failed.
    if ((status != 0 && status != 124)) && "$py" -m bench.ledger retry-base --work "$work" "${ledger[@]}"; then
      mapfile -t args <"$work/$RUN.args" && log=train_${RUN}_base
      stage "$log" 100000 60 "$py" train.py --gin_configs="${args[0]}" --gin_bindings "${args[@]:1}" "${stop[@]}"
    fi
  fi
  if [ "$ACTION" = evaluate ] || grep -q "^Trained to step $STEPS;" "$work/logs/$log.log" 2>/dev/null; then
    stage "eval_$RUN" "${EVAL_SECONDS:-180}" 30 "$py" eval.py --gin_configs="${args[0]}" --gin_bindings "${args[@]:1}"
  fi
  if ! timeout 60 "$py" -m bench.ledger pack "$RUN" --work "$work" --out "$out" "${ledger[@]}"; then
    echo "== pack $RUN failed: the run folder as it is"  # Still resumable: unpack reads its newest checkpoint.
    tar czf "$out/run_$RUN.tar.gz" -C "$work/runs/$RUN" --exclude ./train.lock --exclude './test_preds_step_*' .
  fi
done
timeout 30 "$py" -m bench.ledger pack-window --work "$work" --out "$out" ||
  tar czf "$out/window.tar.gz" -C "$work" logs
echo "== lease done after ${SECONDS}s: $(ls "$out" | tr '\n' ' ')"
