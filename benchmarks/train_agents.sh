#!/usr/bin/env bash
# The shipped agents (data/agents/), trained on the corpus, the old-town corpus and the train city, best.pt
# selected on the val cities (corpus-016, corpus-017, oldtown-005; 1000 fixed episodes each evaluation), never
# on a test city:
#   best-s0 ... best-s8         the `best` preset, 9 seeds, three side by side at a time; then best-e012,
#                               best-e345, best-e678, each three seeds as one agent (`uavrl ensemble`, evaluated on
#                               the val cities); the median ensemble by that validation is shipped as
#                               data/agents/best. LONG=1: 3 seeds on a 500 k-step schedule instead (best-long-sN)
#   best-blind-s0 ... s2        (WHICH=best-blind) the `best` preset with the blind agent (no height channel), 3 seeds,
#                               three side by side: the map question of docs/map_claim.md against best-s0 ... s2
#   proposed-sN, blind-sN       the paper's preset (docs/method.md), with and without the height map,
#                               on one shortened schedule (epsilon annealed over all of it), seed SEED
# Resumable: a run whose folder exists continues from its last checkpoint; a finished one is skipped.
#
#   bash benchmarks/train_agents.sh best|best-blind|paper [OUT]     # OUT defaults to runs/agents
#   SEED=1 PAPER_STEPS=300000 bash benchmarks/train_agents.sh paper runs/agents-v4
set -euo pipefail
WHICH=${1:?best, best-blind or paper}
OUT=${2:-runs/agents}
PAPER_STEPS=${PAPER_STEPS:-100000}
mkdir -p "$OUT"
COMMON=(--dataset corpus --dataset oldtown --dataset train --out "$OUT" --quiet)

source "$(dirname "$0")/one_run.sh"

if [[ $WHICH == paper ]]; then
  PAPER=(--preset paper --steps "$PAPER_STEPS" --eval-every 20000 --set eval_episodes=1000)
  # One seed per call (SEED, default 0): proposed-sN and blind-sN side by side, one per core.
  SEED=${SEED:-0}
  one "proposed-s$SEED" "${PAPER[@]}" --seed "$SEED" --agent dqn &
  one "blind-s$SEED" "${PAPER[@]}" --seed "$SEED" --agent blind &
elif [[ $WHICH == best-blind ]]; then
  side_by_side best-blind "0 1 2" --preset best --agent blind
else
  if [[ ${LONG:-0} == 1 ]]; then
    for seed in 0 1 2; do one "best-long-s$seed" --preset best --steps 500000 --seed "$seed" & done
  else
    for trio in "0 1 2" "3 4 5" "6 7 8"; do
      for seed in $trio; do one "best-s$seed" --preset best --seed "$seed" & done
      wait
      ensemble_of "$OUT/best-e${trio// /}" "$OUT/best" "$trio"
    done
  fi
fi
wait
