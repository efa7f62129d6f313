# Sourced by benchmarks/levers.sh and benchmarks/train_agents.sh: `one NAME ARGS...` trains the run
# OUT/NAME with `uavrl train "${COMMON[@]}" --name NAME ARGS...` (one torch thread), continues it with
# `--resume` when its folder holds a checkpoint, skips it once its last evaluation reached total_steps,
# and appends its wall time to OUT/wall.txt.
one() {
  local name=$1; shift
  if [[ -f "$OUT/$name/eval.parquet" ]] && python - "$OUT/$name" <<'PY'
import json, os, sys, pandas as pd
total = json.load(open(f"{sys.argv[1]}/run.json"))["config"]["total_steps"]
ev = pd.read_parquet(f"{sys.argv[1]}/eval.parquet")
# os._exit: no interpreter teardown, where pyarrow's threads once aborted the check (exit 134) and a finished run
# was taken for an unfinished one.
os._exit(0 if len(ev) and ev.step.max() >= total else 1)
PY
  then echo "$name: done"; return; fi
  local t0=$SECONDS
  if [[ -d "$OUT/$name/checkpoints/last" ]]; then
    OMP_NUM_THREADS=1 uavrl train --resume "$OUT/$name" --quiet
  else
    rm -rf "${OUT:?}/$name"
    OMP_NUM_THREADS=1 uavrl train "${COMMON[@]}" --name "$name" "$@"
  fi
  echo "$name: $((SECONDS - t0)) s" | tee -a "$OUT/wall.txt"
}

# `side_by_side NAME "SEEDS" ARGS...` trains NAME-sN with `--seed N ARGS...` for every seed N in SEEDS at once (each
# a `one` run on one torch thread), and waits for them all.
side_by_side() {
  local name=$1 seeds=$2; shift 2
  for seed in $seeds; do one "$name-s$seed" --seed "$seed" "$@" & done
  wait
}

# `lever SWITCH NAME ARGS...`: when SWITCH=1, `side_by_side NAME "$SWITCH_SEEDS" ARGS...` (seed 0 unless set).
lever() {
  local switch=$1 name=$2; shift 2
  local seeds_var="${switch}_SEEDS"
  [[ ${!switch:-0} == 1 ]] || return 0
  side_by_side "$name" "${!seeds_var:-0}" "$@"
}

# `ensemble_of FOLDER RUN_PREFIX "SEEDS"`: `uavrl ensemble` of the runs RUN_PREFIX-sN (N in SEEDS) into FOLDER, once every
# one of them holds a best.pt; an existing FOLDER is kept.
ensemble_of() {
  local folder=$1 prefix=$2 members=()
  for seed in $3; do [[ -f $prefix-s$seed/checkpoints/best.pt ]] && members+=("$prefix-s$seed"); done
  if [[ ${#members[@]} == $(wc -w <<< "$3") && ! -d $folder ]]; then
    OMP_NUM_THREADS=1 uavrl ensemble "${members[@]}" --out "$folder" --quiet
  fi
}
