# Stages inside a time budget, for the scripts a lent GPU runs (bench/gpu_check.sh, bench/lease.sh): source it,
# then set budget (seconds for the whole script, counted by bash's SECONDS), reserve (seconds kept for what
# follows the last stage), stage_dir (each stage's log NAME.log and the table stages.tsv go there) and, if 20 s are
# too few, grace (seconds a stopped stage has between SIGTERM and SIGKILL). A stage ends by budget - reserve.

stage_left() {  # Seconds a stage starting now may run: what the budget leaves, less the reserve and the grace.
  echo $((budget - SECONDS - reserve - ${grace:-20}))
}

stage() {  # stage NAME MAX_SECONDS MIN_SECONDS COMMAND...: COMMAND within what is left, its output in NAME.log.
  # Returns COMMAND's status (1 when skipped); stage_cut=1 when the budget skipped or stopped it (SIGTERM at its
  # limit: status 124; SIGKILL the grace later: 137): a cut, not a failure.
  local name=$1 limit=$2 least=$3 t0=$SECONDS status left cut=''
  shift 3
  stage_cut=0
  left=$(stage_left)
  ((left < limit)) && limit=$left
  if ((limit < least)); then
    echo "== $name: skipped (${left}s of the budget left, it needs ${least}s)"
    printf '%s\tskipped\t0\n' "$name" >>"$stage_dir/stages.tsv"
    stage_cut=1
    return 1
  fi
  echo "== $name: $(date +%T), limit ${limit}s"
  # A stopped stage gets SIGTERM (training saves a checkpoint and exits), then SIGKILL the grace later.
  timeout -s TERM -k "${grace:-20}" "$limit" "$@" >"$stage_dir/$name.log" 2>&1
  status=$?
  # SECONDS counts whole seconds, so a stage that ran its limit shows at least the limit.
  if ((status == 124 || status == 137)) && ((SECONDS - t0 >= limit)); then
    stage_cut=1 cut=': cut by the budget'
  fi
  echo "== $name: status $status after $((SECONDS - t0))s$cut"
  printf '%s\t%s\t%s\n' "$name" "$status" "$((SECONDS - t0))" >>"$stage_dir/stages.tsv"
  tail -n 12 "$stage_dir/$name.log"
  return $status
}
