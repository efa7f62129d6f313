#!/usr/bin/env bash
# The lever table of the `best` preset (README, "What each lever did"): one short run per lever,
# trained on the corpus and the train city, best.pt selected on the val cities (corpus-016,
# corpus-017; 1000 fixed episodes), never on a test city. R0 is the old `best` preset; R1-R3 add
# one reward or observation change each to the row before; the step cost (R1) lost 30 points, so
# S1-S3 each add one lever to R0 alone; S2 (the visited channel) also runs with seeds 1 and 2
# (S2-s1, S2-s2), to compare its 3 seeds with the 3 seeds of the 500 k schedule (benchmarks/train_agents.sh).
# Two lanes run side by side, one torch thread each (the 2 cores). Resumable: a run whose folder
# exists continues from its last checkpoint (`uavrl train --resume`); a finished one is skipped.
#
#   bash benchmarks/levers.sh [STEPS] [OUT]      # defaults: 150000, runs/levers
set -euo pipefail
STEPS=${1:-150000}
OUT=${2:-runs/levers}
mkdir -p "$OUT"
# The rows start from the `best` preset as it was before this table (no visited channel, 1 M-step schedule
# shortened to STEPS): the lever S2 is what the preset has now.
COMMON=(--dataset corpus --dataset train --preset best --steps "$STEPS" --eval-every 50000 --set eval_episodes=1000
        --set env.visited_channel=false --out "$OUT" --quiet)
R0=()
R1=(--set env.c_e=0.3 --set env.step_cost=0.5)
R2=("${R1[@]}" --set env.shaping=1)
R3=("${R2[@]}" --set env.visited_channel=true)
S1=(--set env.shaping=1)
S2=(--set env.visited_channel=true)
S3=(--set env.symmetries=8 --set env.far_starts=0.5)
B1=("${S2[@]}" --set env.success_bonus=100)
B2=("${B1[@]}" --set env.c_e=0.3)
B3=("${S2[@]}" --set env.success_bonus=300)
B4=("${B1[@]}" --set env.far_starts=0.5)

source "$(dirname "$0")/one_run.sh"

(one R0 "${R0[@]}"; one R2 "${R2[@]}"; one S1 "${S1[@]}"; one S3 "${S3[@]}"; one S2-s1 "${S2[@]}" --seed 1; one B1 "${B1[@]}"; one B3 "${B3[@]}"; one B3-s1 "${B3[@]}" --seed 1; one B1-s1 "${B1[@]}" --seed 1) &
(one R1 "${R1[@]}"; one R3 "${R3[@]}"; one S2 "${S2[@]}"; one S2-s2 "${S2[@]}" --seed 2; one B2 "${B2[@]}"; one B4 "${B4[@]}"; one B3-s2 "${B3[@]}" --seed 2; one B1-s2 "${B1[@]}" --seed 2) &
wait
