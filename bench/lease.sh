#!/usr/bin/env bash
# One GPU window moves the ledger of paper-length runs forward (bench/ledger.toml; docs/benchmarks.md, "GPU windows:
# the ledger"). The one command a window runs, from the repository's root, `bash bench/lease.sh`, carrying .whl and
# .devdata (`python -m bench.prepare_lease` fills them and prints the call). The whole script ends within BUDGET
# seconds: each stage has a limit of its own and ends by BUDGET - reserve (a stage that no longer fits is skipped
# and says so; a stopped one gets SIGTERM, on which training saves a checkpoint, and SIGKILL the grace later), and
# what follows the last stage fits in the reserve:
#   1. the wheels of .whl installed to /tmp/site; `bench.ledger plan`: the plan, printed (jax seeing no GPU stops the
#      lease here, with nothing packed);
#   2. on a GPU whose kind has not timed this code's step yet (results/gpu/ledger/timed.json): the step variants
#      (bench.step_variants), RegNeRF's step beside mip-NeRF's (bench.device) and the fused layer's GPU tests, within
#      the ledger's variants_seconds;
#   3. the first unfinished run resumed from its committed checkpoint with its variant (a new run: the fastest
#      correct one timed), trained until the budget with a learning-curve point every curve_every steps; evaluated
#      on every test view once finished, then the next run; each run packed as it ends. A budget cut is never a
#      failure; a new run whose variant failed before its first checkpoint goes again with base;
#   4. the window's logs and timings packed. Into $OUT (what comes back, 8 files at most): lease.log,
#      window.tar.gz, run_RUN.tar.gz and eval_RUN.tar.gz per run. `python -m bench.ledger unpack FOLDER` commits them.
# Environment: OUT (required), BUDGET (seconds for the whole script, default 530: the device call's 590 less a
# minute), PYTHON (python3), LEASE_WORK (an empty folder for run folders and logs, default a new one under /tmp),
# LEDGER, RESULTS, DATA (bench.ledger's --ledger, --results, --data), EVAL_SECONDS (an evaluation's limit, default
# 180: 13 views take about 20 s on an H100), and for dry runs and tests: LEASE_ON_CPU=1 (a window on the CPU, for the
# tests' tiny ledger), GRACE (the grace, default 40), STOP_AT_STEP (training stops after this step).
set -u
cd "$(dirname "$0")/.." || exit 2
out=${OUT:?OUT: the folder that comes back from the window} budget=${BUDGET:-530} py=${PYTHON:-python3}
work=${LEASE_WORK:-$(mktemp -d /tmp/lease.XXXXXX)}
# Seconds from a stage's SIGTERM to its SIGKILL: training stopped by the budget finishes its step, the curve point
# in progress (13 views, their render compiled at the first point) and a checkpoint; a checkpoint every
# checkpoint_every steps bounds what a SIGKILL loses.
grace=${GRACE:-40}
# What follows the last stage, each part with its limit: a run's packing (SIGKILL kill_s after its SIGTERM), the
# plain tar if that failed, the window's packing, its plain tar, and 5 s for the script's own lines.
pack_s=25 window_s=15 tar_s=10 kill_s=5
reserve=$((pack_s + kill_s + tar_s + window_s + kill_s + tar_s + 5))
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false JAX_COMPILATION_CACHE_DIR=$work/jax_cache
ledger=(--ledger "${LEDGER:-bench/ledger.toml}" --results "${RESULTS:-results/gpu/ledger}" --data "${DATA:-.devdata}")
mkdir -p "$out" "$work/logs" || exit 2
[ -z "$(ls -A "$work/logs")" ] || { echo "LEASE_WORK $work is not new; expected an empty folder"; exit 2; }
exec > >(tee -a "$out/lease.log") 2>&1
: >"$work/logs/stages.tsv"
stage_dir=$work/logs
source bench/stages.sh  # stage NAME MAX MIN COMMAND...

if compgen -G '.whl/*.whl' >/dev/null &&  # The packages the GPU image lacks (bench.prepare_lease).
  stage wheels 120 10 "$py" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target /tmp/site .whl/*.whl; then
  export PYTHONPATH=/tmp/site${PYTHONPATH:+:$PYTHONPATH}
fi
command -v nvidia-smi >/dev/null && stage nvidia_smi 20 5 nvidia-smi --format=csv --filename="$work/nvidia_smi.csv" \
  --query-gpu=name,memory.total,driver_version,clocks.sm,clocks.mem,temperature.gpu,power.draw
on_cpu=() && [ "${LEASE_ON_CPU:-0}" = 1 ] && on_cpu=(--allow_cpu)
stage plan 90 10 "$py" -m bench.ledger plan --work "$work" --budget "$budget" "${on_cpu[@]}" "${ledger[@]}" || {
  status=$?
  echo "== lease stopped after ${SECONDS}s: no plan, nothing packed"
  exit "$status"
}
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
    status=$?  # A cut (by the budget, after SIGTERM or the grace's SIGKILL; or skipped) saved what it trained.
    if ((status != 0 && !stage_cut)) &&  # Failed: bench.ledger says whether it goes again with base.
      stage "retry_$RUN" 60 10 "$py" -m bench.ledger retry-base --work "$work" "${ledger[@]}"; then
      mapfile -t args <"$work/$RUN.args" && log=train_${RUN}_base
      stage "$log" 100000 60 "$py" train.py --gin_configs="${args[0]}" --gin_bindings "${args[@]:1}" "${stop[@]}"
    fi
  fi
  if [ "$ACTION" = evaluate ] || grep -q "^Trained to step $STEPS;" "$work/logs/$log.log" 2>/dev/null; then
    stage "eval_$RUN" "${EVAL_SECONDS:-180}" 30 "$py" eval.py --gin_configs="${args[0]}" --gin_bindings "${args[@]:1}"
  fi
  if ! timeout -k "$kill_s" "$pack_s" "$py" -m bench.ledger pack "$RUN" --work "$work" --out "$out" "${ledger[@]}" &&
    [ -d "$work/runs/$RUN" ]; then
    echo "== pack $RUN failed: the run folder as it is"  # Still resumable: unpack reads its newest checkpoint.
    timeout -s KILL "$tar_s" tar czf "$out/run_$RUN.tar.gz" -C "$work/runs/$RUN" --exclude ./train.lock \
      --exclude './test_preds_step_*' .
  fi
done
timeout -k "$kill_s" "$window_s" "$py" -m bench.ledger pack-window --work "$work" --out "$out" ||
  timeout -s KILL "$tar_s" tar czf "$out/window.tar.gz" -C "$work" \
    $(cd "$work" && ls -d plan.txt window.json outcomes.json nvidia_smi.csv logs variants 2>/dev/null)
echo "== lease done after ${SECONDS}s: $(ls "$out" | tr '\n' ' ')"
