#!/usr/bin/env bash
# The shipped agents (data/agents/), trained on the corpus, the old-town corpus and the train city, best.pt
# selected on the val cities (corpus-016, corpus-017, oldtown-005; 1000 fixed episodes each evaluation), never
# on a test city:
#   best-s0, best-s1, best-s2   the `best` preset, 3 seeds (the median seed by validation is shipped as
#                               data/agents/best); LONG=1: on a 500 k-step schedule instead (best-long-sN)
#   proposed-sN, blind-sN       the paper's preset (docs/method.md), with and without the height map,
#                               on one shortened schedule (epsilon annealed over all of it), seed SEED
# Resumable: a run whose folder exists continues from its last checkpoint; a finished one is skipped.
#
#   bash benchmarks/train_agents.sh best|paper [OUT]     # OUT defaults to runs/agents
#   SEED=1 PAPER_STEPS=300000 bash benchmarks/train_agents.sh paper runs/agents-v4
set -euo pipefail
WHICH=${1:?best or paper}
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
else
  if [[ ${LONG:-0} == 1 ]]; then
    for seed in 0 1 2; do one "best-long-s$seed" --preset best --steps 500000 --seed "$seed" & done
  else
    # Two lanes on the 2 cores: seeds 0 and 2 in one, seed 1 in the other.
    (one best-s0 --preset best --seed 0; one best-s2 --preset best --seed 2) &
    one best-s1 --preset best --seed 1 &
  fi
fi
wait
