#!/usr/bin/env bash
# The lever table of the `best` preset (README, "What each lever did"): one short run per lever,
# trained on the corpus and the train city, best.pt selected on the val cities (corpus-016,
# corpus-017; 1000 fixed episodes), never on a test city. R0 is the old `best` preset; R1-R3 add
# one reward or observation change each to the row before; the step cost (R1) lost 30 points, so
# S1-S3 each add one lever to R0 alone; S2 (the visited channel) also runs with seeds 1 and 2
# (S2-s1, S2-s2), to compare its 3 seeds with the 3 seeds of the 500 k schedule (benchmarks/train_agents.sh).
# `best-dqn` is the `best` preset before PQN (A1L; the runs before PQN were trained as `--preset best` when it was
# A1L or, earlier, less). Two lanes run side by side, one torch thread each (the 2 cores). Resumable: a run whose folder
# exists continues from its last checkpoint (`uavrl train --resume`); a finished one is skipped.
#
# B1-B4 add a success bonus to S2. With V2=1 it trains instead the rows on top of N1 (S2 + success bonus 100,
# trained with the old-town cities too; the `best` preset less its revisit penalty) into runs/levers-v2: F1, F2, G1 (3 seeds),
# G2, C1 (2 seeds); README, "The success bonus and the old-town corpus".
#
# With AUX=1 it trains the rows of the genie-move head into runs/aux (README, "The genie-move head"): A1 (N2 +
# aux_genie 1, 3 seeds), A03 and A3 (head weights 0.3 and 3), A1L (A1 on a 300 k schedule, the `best-dqn` preset now,
# 3 seeds), W91 (A1 with a 91-cell window), Y8 (A1L with the 8 symmetries, 3 seeds), FS (A1L with far starts 0.5, 3 seeds),
# A1XL (A1L on 600 k steps) and CZ4 (A1L with the context channels in blocks of 4 x 4 cells).
#
# With V5=1 it trains the rows on this release's maps (1.6e7 rays per user, -75 dBm) into runs/levers-v5, each the
# `best-dqn` preset (A1L) with one change, seed 0: T5 (training t_max 500, the test's), G995 (gamma 0.995), RR2 (an update
# every 8 env steps instead of 16: twice the replay ratio) and H512 (fully connected layers of 512).
#
#   bash benchmarks/levers.sh [STEPS] [OUT]      # defaults: 150000, runs/levers
#   V5=1 bash benchmarks/levers.sh               # the rows on the 1.6e7-ray maps, runs/levers-v5
#   H5=1 bash benchmarks/levers.sh               # H512 (V5) with 3 seeds, runs/levers-v5
#   OT=1 bash benchmarks/levers.sh               # the old-town cities drawn 3 times as often, runs/levers-v5
#   HALF=1 bash benchmarks/levers.sh             # A1L on half the training cities (3 seeds), runs/levers-v5
#   PQN=1 [PQN_SEEDS="0 1 2"] bash benchmarks/levers.sh   # A1L learnt by PQN instead of replay DQN, runs/levers-v5
#   PQNV=1 bash benchmarks/levers.sh             # PQN with the convolutional network, and with lambda 0.9
#   GRU=1 [GRU_SEEDS="0 1 2"] bash benchmarks/levers.sh   # PQN with a recurrent core, 16-move rollouts
#   GRUV=1 [GRUV_SEEDS="0 1 2"] [GRUV_ROLLOUT=64] bash benchmarks/levers.sh # the core on 32-move rollouts (the
#                                                `best` preset now), or on 64-move ones; the seeds side by side
#   OT10=1 bash benchmarks/levers.sh             # GRU-R32 with 3 more old-town training cities (3 seeds)
#   LONG=1 [LONG_SEEDS="0 1 2"] [LONG_STEPS=600000] bash benchmarks/levers.sh  # the `best` preset on a longer
#                                                schedule (runs GRU-R32-L600-sN), the seeds side by side
#   GRUT5=1 [GRUT5_SEEDS="0 1 2"] bash benchmarks/levers.sh  # the `best` preset on training episodes of 500 moves
#                                                (the test's t_max; runs GRU-R32-T5-sN), the seeds side by side
#   GRUH=1 [GRUH_SEEDS="0 1 2"] bash benchmarks/levers.sh   # the `best` preset with a core (and layers) of 512
#                                                (runs GRU-R32-H512-sN), the seeds side by side
#   TRP=1 [TRP_SEEDS="0 1 2"] bash benchmarks/levers.sh     # the `best` preset acting in training by its test rule
#                                                (train_revisit_penalty=1; runs GRU-R32-TRP-sN), the seeds side by side
#   RVC=1 [RVC_SEEDS="0 1 2"] bash benchmarks/levers.sh     # the `best` preset with a revisit cost of 1 in its
#                                                training reward (env.revisit_cost=1; runs GRU-R32-RVC-sN)
#   EPS=1 [EPS_SEEDS="0 1 2"] bash benchmarks/levers.sh     # the `best` preset exploring to the end at the test's
#                                                random-move rate (eps_end=0.096; runs GRU-R32-EPS-sN)
#   Y8=1 [Y8_SEEDS="0 1 2"] bash benchmarks/levers.sh       # the `best` preset on the 8 symmetries of the square
#                                                (env.symmetries=8; runs GRU-R32-Y8-sN)
#   PX=1 [PX_SEEDS="0 1 2"] bash benchmarks/levers.sh       # the `best` preset with the surround max- and min-pooled
#                                                too (pool_extremes=true; runs GRU-R32-PX-sN)
#   SH=1 [SH_SEEDS="0 1 2"] bash benchmarks/levers.sh       # the `best` preset with potential-based shaping from the
#                                                genie's distance in training (env.shaping=1; runs GRU-R32-SH-sN)
#   HM=1 [HM_SEEDS="0 1 2"] bash benchmarks/levers.sh       # GRU-R32 with the homing channel (the best SINR
#                                                measured so far as a cone around its cell; runs GRU-R32-HM-sN)
#   PM=1 [PM_SEEDS="0 1 2"] bash benchmarks/levers.sh       # GRU-R32 with the fovea's middle view (the centre 31
#                                                cells at half resolution; runs GRU-R32-PM-sN)
#   HTRP=1 [HTRP_SEEDS="0 1 2"] bash benchmarks/levers.sh   # HM acting in training by its test rule
#                                                (train_revisit_penalty=1): the `best` preset until HG98 (runs GRU-R32-HM-TRP-sN)
#   HS2=1 [HS2_SEEDS="0 1 2"] bash benchmarks/levers.sh     # HM with a homing cone of 2 dB a cell
#                                                (env.homing_slope_db=2; runs GRU-R32-HM-S2-sN)
#   HCE=1 [HCE_SEEDS="0 1 2"] bash benchmarks/levers.sh     # HTRP with a new-cell bonus of 0.6
#                                                (env.c_e=0.6; runs GRU-R32-HM-TRP-CE6-sN)
#   HG98=1 [HG98_SEEDS="0 1 2"] bash benchmarks/levers.sh   # HTRP with gamma 0.98: the `best` preset now
#                                                (runs GRU-R32-HM-TRP-G98-sN)
#   HG97=1 [HG97_SEEDS="0 1 2"] bash benchmarks/levers.sh   # the `best` preset with gamma 0.97
#                                                (runs GRU-R32-HM-TRP-G97-sN)
#   ENSEMBLE=ROW bash benchmarks/levers.sh       # `uavrl ensemble` of the row's seeds 0-2, 3-5 and 6-8 (those trained),
#                                                into runs/ensembles/ROW-E012, -E345, -E678 (e.g. ROW=GRU-R32-HM-TRP-G98)
#   V2=1 bash benchmarks/levers.sh               # the N1 rows, runs/levers-v2
#   AUX=1 bash benchmarks/levers.sh              # the A rows, runs/aux
set -euo pipefail
source "$(dirname "$0")/one_run.sh"
if [[ ${AUX:-0} == 1 ]]; then
  OUT=runs/aux
  mkdir -p "$OUT"
  COMMON=(--dataset corpus --dataset oldtown --dataset train --preset best-dqn --out "$OUT" --quiet)
  A1=(--set aux_genie=1.0 --steps 150000)
  (one A1-s0 --seed 0 "${A1[@]}"; one A1-s1 --seed 1 "${A1[@]}"; one A3-s0 --seed 0 --set aux_genie=3.0 --steps 150000
   one A1L-s1 --seed 1 --set aux_genie=1.0 --steps 300000; one W91-s0 --seed 0 "${A1[@]}" --set env.window=91) &
  (one A1-s2 --seed 2 "${A1[@]}"; one A03-s0 --seed 0 --set aux_genie=0.3 --steps 150000
   one A1L-s0 --seed 0 --set aux_genie=1.0 --steps 300000; one A1L-s2 --seed 2 --set aux_genie=1.0 --steps 300000) &
  wait
  A1L=(--set aux_genie=1.0 --steps 300000)
  (one Y8-s0 --seed 0 "${A1L[@]}" --set env.symmetries=8; one FS-s1 --seed 1 "${A1L[@]}" --set env.far_starts=0.5) &
  (one FS-s0 --seed 0 "${A1L[@]}" --set env.far_starts=0.5; one FS-s2 --seed 2 "${A1L[@]}" --set env.far_starts=0.5) &
  wait
  (one A1XL-s0 --seed 0 --set aux_genie=1.0 --steps 600000) &
  (one CZ4-s0 --seed 0 "${A1L[@]}" --set env.context_zoom=4) &
  wait
  (one Y8-s1 --seed 1 "${A1L[@]}" --set env.symmetries=8) &
  (one Y8-s2 --seed 2 "${A1L[@]}" --set env.symmetries=8) &
  wait
  exit 0
fi
V5_ROWS=0  # any of the switches whose rows train into runs/levers-v5
for switch in V5 H5 HALF OT PQN PQNV GRU GRUV OT10 LONG GRUT5 GRUH TRP RVC EPS Y8 PX SH HM PM HTRP HS2 HCE HG98 HG97; do [[ ${!switch:-0} == 1 ]] && V5_ROWS=1; done
[[ -n ${ENSEMBLE:-} ]] && V5_ROWS=1
if [[ $V5_ROWS == 1 ]]; then
  # The rows on this release's maps, side by side in one OUT: the `best-dqn` preset (A1L) with one change each.
  OUT=runs/levers-v5
  mkdir -p "$OUT"
  TAIL=(--preset best-dqn --out "$OUT" --quiet)
  COMMON=(--dataset corpus --dataset oldtown --dataset train "${TAIL[@]}")
  if [[ ${V5:-0} == 1 ]]; then
    (one T5-s0 --seed 0 --set env.t_max=500; one RR2-s0 --seed 0 --set train_every=8) &
    (one G995-s0 --seed 0 --set gamma=0.995; one H512-s0 --seed 0 --set hidden=512) &
    wait
    # T5 tied A1L on seed 0: seeds 1 and 2.
    (one T5-s1 --seed 1 --set env.t_max=500) &
    (one T5-s2 --seed 2 --set env.t_max=500) &
    wait
  fi
  if [[ ${H5:-0} == 1 ]]; then
    # H512 took fewer steps than A1L on every validation city (seed 0): seeds 1 and 2, one lane (the paper pair held
    # the cores).
    for seed in 0 1 2; do one "H512-s$seed" --seed "$seed" --set hidden=512; done
  fi
  if [[ ${OT:-0} == 1 ]]; then
    # The old-town cities (the densest style, the hardest validation city) drawn 3 times as often as the others
    # (env.city_weights; 46 % of the training episodes instead of 22 %), seed 0.
    one OT3-s0 --seed 0 --set 'env.city_weights={"oldtown": 3}'
  fi
  if [[ ${HALF:-0} == 1 ]]; then
    # Does validation grow with the number of training cities? A1L on half of them (8 corpus, 3 old-town and the train
    # city: 12 of 22), selected on the same validation cities, seeds 0 and 1 side by side, then seed 2.
    COMMON=()
    for c in corpus-00{0..7} oldtown-00{0..2} train; do COMMON+=(--dataset "$c"); done
    COMMON+=(--val-dataset corpus-016 --val-dataset corpus-017 --val-dataset oldtown-005 "${TAIL[@]}")
    one HALF-s0 --seed 0 &
    one HALF-s1 --seed 1 &
    wait
    one HALF-s2 --seed 2
  fi
  # PQN's runs were trained as `--preset best` (A1L then) with these settings, which are the `best-pqn` preset now; the
  # GRU rows as `--preset best` (best-pqn then) with these settings and recurrent=true: the `best` preset until GRUV.
  COMMON=(--dataset corpus --dataset oldtown --dataset train --preset best-pqn --out "$OUT" --quiet)
  PQN=(--set learner=pqn --set num_envs=128 --set rollout_steps=16 --set epochs=4 --set layer_norm=true)
  if [[ ${PQN:-0} == 1 ]]; then
    # The learner instead of the levers around it: PQN (rl/agent/pqn.py; Q(lambda) on rollouts of 128 envs x 16 moves,
    # 4 epochs of batches of 128, layer norm, no replay, no target network) on A1L's network, reward and schedule.
    for seed in ${PQN_SEEDS:-0}; do one "PQN-s$seed" --seed "$seed" "${PQN[@]}"; done
  fi
  if [[ ${PQNV:-0} == 1 ]]; then
    # Two changes PQN's cheaper updates afford (seed 0): the paper's convolutional network on the full window (fc
    # without dropout) instead of the foveated one, and lambda 0.9 (longer returns).
    one PQN-CNN-s0 --seed 0 "${PQN[@]}" --set network=paper --set dropout=0
    one PQN-L9-s0 --seed 0 "${PQN[@]}" --set q_lambda=0.9
  fi
  if [[ ${GRU:-0} == 1 ]]; then
    # A memory of the whole search, beyond the window: a GRU cell between the features and the heads, its state reset
    # at each episode's start, learnt on whole env rollouts from the state each began with (rl/agent/pqn.py).
    for seed in ${GRU_SEEDS:-0}; do one "PQN-GRU-s$seed" --seed "$seed" "${PQN[@]}" --set recurrent=true; done
  fi
  # The rows up to HM and PM were trained with the `best` preset before it had the homing channel and the revisit
  # penalty in training (GRU-R32): R32 keeps them as they ran; HM is R32 with the homing channel.
  # The `best` preset discounts at 0.98 since HG98; the rows before it (up to HCE) ran at 0.99.
  R32=(--preset best --set gamma=0.99 --set env.homing_channel=false --set train_revisit_penalty=0)
  HM=(--preset best --set gamma=0.99 --set train_revisit_penalty=0)
  if [[ ${GRUV:-0} == 1 ]]; then
    # The core learnt over longer stretches of each search: rollouts of 32 moves in 64 envs (the same 2048 env steps
    # and 64 minibatches of 128 samples a round; 4 envs x 32 moves each): GRU-R32, the `best` preset until the homing channel.
    # GRUV_ROLLOUT=64: rollouts of 64 moves in 32 envs (2 envs a minibatch), runs GRU-R64-sN.
    R=${GRUV_ROLLOUT:-32}
    side_by_side "GRU-R$R" "${GRUV_SEEDS:-0}" "${R32[@]}" --set num_envs=$((2048 / R)) --set rollout_steps="$R"
  fi
  if [[ ${OT10:-0} == 1 ]]; then
    # More historic centres: the `best` preset (GRU-R32) trained with oldtown-006 to -008 too (8 old-town cities
    # instead of 5) and selected with oldtown-009 too (built as val: 4 validation cities). Two lanes: seeds 0 and 2 in
    # one, seed 1 in the other. Needs oldtown-006 to -009 traced and built first (README, "More old-town cities").
    (one GRU-R32-OT8-s0 --seed 0 "${R32[@]}"; one GRU-R32-OT8-s2 --seed 2 "${R32[@]}") &
    one GRU-R32-OT8-s1 --seed 1 "${R32[@]}" &
    wait
  fi
  if [[ ${LONG:-0} == 1 ]]; then
    # The `best` preset (GRU-R32) on a longer schedule: its validation success still rose at its last evaluation
    # (300 k steps) in each of its 3 seeds. Epsilon and the learning rate anneal over the longer schedule.
    N=${LONG_STEPS:-600000}
    side_by_side "GRU-R32-L$((N / 1000))" "${LONG_SEEDS:-0}" "${R32[@]}" --steps "$N"
  fi
  # The `best` preset with training episodes as long as the test's (500 moves instead of 300): the searches that
  # fail in the old town run to the limit, so the core may learn more of a search's late part.
  lever GRUT5 GRU-R32-T5 "${R32[@]}" --set env.t_max=500
  # The `best` preset twice as wide (hidden 512: the fully connected layers and the GRU state), for the old town,
  # where the searches are long and the core must hold more of the route.
  lever GRUH GRU-R32-H512 "${R32[@]}" --set hidden=512
  # The `best` preset moving in training as it is tested: the greedy move less 1 per earlier visit of the cell it
  # leads to (the test rule's revisit penalty, worth 6 points of validation at test time), so that the returns
  # it learns are those of the policy it will act by.
  lever TRP GRU-R32-TRP "${R32[@]}" --set train_revisit_penalty=1
  # The same penalty as a cost in the training reward (1 per earlier visit of the cell a move enters), so that
  # the Q-values themselves learn to leave visited ground.
  lever RVC GRU-R32-RVC "${R32[@]}" --set env.revisit_cost=1
  # The `best` preset ending its exploration at the test's rate of random moves (0.096, not 0.02): the returns it
  # learns, and the recoveries its core learns, are those of the noisy policy it is tested as.
  lever EPS GRU-R32-EPS "${R32[@]}" --set eps_end=0.096
  # The `best` preset on the 8 symmetries of the square (the mirrors too): twice the street layouts per city,
  # for cities it never saw.
  lever Y8 GRU-R32-Y8 "${R32[@]}" --set env.symmetries=8
  # The `best` preset seeing its surround max- and min-pooled as well as averaged: in the old town's lanes of 2
  # cells a 5 x 5 mean blurs an open lane among walls, and one unvisited cell among visited ones, into one number.
  lever PX GRU-R32-PX "${R32[@]}" --set pool_extremes=true
  # The `best` preset with potential-based shaping from the genie's distance (training only; the optimal policy is
  # unchanged): in the old town the agent fails near its start, where the SINR gives no direction and the
  # success bonus comes late; shaping credits each move towards a target at once.
  lever SH GRU-R32-SH "${R32[@]}" --set env.shaping=1
  # GRU-R32 with the homing channel: in the old town a failed search leaves the live cells around the user
  # (a median 133 moves in) and wanders the dead ones, where no SINR points back; the cone of the best SINR measured
  # so far points back to where it was measured from anywhere in the window, however far that is.
  lever HM GRU-R32-HM "${HM[@]}"
  # GRU-R32 with the fovea's middle view: the old town's searches fail near their start, with the target
  # a few lanes away, beyond the 15-cell centre, where the surround's 5 x 5 means blur lanes of 1 to 2 cells.
  lever PM GRU-R32-PM "${R32[@]}" --set pool_middle=true
  # On top of HM: its moves in training by the test rule (the revisit penalty; TRP took fewer steps in the old town):
  # the `best` preset now; and a cone twice as steep (2 dB a cell: more salient to the first layer, visible to 75
  # cells instead of 150).
  lever HTRP GRU-R32-HM-TRP --preset best --set gamma=0.99
  lever HS2 GRU-R32-HM-S2 "${HM[@]}" --set env.homing_slope_db=2
  # The `best` preset (HTRP) with half the new-cell bonus (0.6): with a way home, wandering need not pay as much;
  # for the steps the channel added in corpus-016.
  lever HCE GRU-R32-HM-TRP-CE6 --preset best --set gamma=0.99 --set env.c_e=0.6
  # HTRP discounting at 0.98 instead of 0.99 (the `best` preset now; `--set gamma=0.98` as the runs were trained): with the success bonus of 100, each move's delay
  # costs about 1 (0.99) or 2 (0.98) of discounted bonus near a target, against the new-cell bonus of 1.2 it earns by
  # wandering on; for the steps in the dense cities.
  lever HG98 GRU-R32-HM-TRP-G98 --preset best --set gamma=0.98
  # The next point on the discount's axis: 0.97 (a move's delay costs about 3 of the success bonus near a target).
  lever HG97 GRU-R32-HM-TRP-G97 --preset best --set gamma=0.97
  if [[ -n ${ENSEMBLE:-} ]]; then
    # Three seeds of one row as one agent (the mean of their Q values), for each trio of seeds trained; each is
    # evaluated on the validation cities as a run is (rl/agent/ensemble.py). An existing ensemble is kept.
    mkdir -p runs/ensembles
    for trio in "0 1 2" "3 4 5" "6 7 8"; do ensemble_of "runs/ensembles/$ENSEMBLE-E${trio// /}" "$OUT/$ENSEMBLE" "$trio"; done
  fi
  exit 0
fi
if [[ ${V2:-0} == 1 ]]; then
  OUT=runs/levers-v2
  mkdir -p "$OUT"
  COMMON=(--dataset corpus --dataset oldtown --dataset train --preset best-dqn --steps 150000 --set test_revisit_penalty=0 --set aux_genie=0
          --out "$OUT" --quiet)
  CONV=(--set network=paper --set "conv_channels=[16,32,32]" --set dropout=0)
  (one F1 --seed 0 --set fovea=21; one G1 --seed 0 --set gamma=0.97; one G1-s1 --seed 1 --set gamma=0.97
   one C1-s0 --seed 0 "${CONV[@]}") &
  (one F2 --seed 0 --set hidden=512; one G2 --seed 0 --set n_step=5; one G1-s2 --seed 2 --set gamma=0.97
   one C1-s1 --seed 1 "${CONV[@]}") &
  wait
  exit 0
fi
STEPS=${1:-150000}
OUT=${2:-runs/levers}
mkdir -p "$OUT"
# The rows start from the `best` preset as it was before this table (no visited channel, no success bonus, no revisit
# penalty, no genie-move head, 1 M-step schedule shortened to STEPS).
COMMON=(--dataset corpus --dataset train --preset best-dqn --steps "$STEPS" --eval-every 50000 --set eval_episodes=1000
        --set env.visited_channel=false --set env.success_bonus=0 --set test_revisit_penalty=0 --set aux_genie=0
        --out "$OUT" --quiet)
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

(one R0 "${R0[@]}"; one R2 "${R2[@]}"; one S1 "${S1[@]}"; one S3 "${S3[@]}"; one S2-s1 "${S2[@]}" --seed 1; one B1 "${B1[@]}"; one B3 "${B3[@]}"; one B3-s1 "${B3[@]}" --seed 1; one B1-s1 "${B1[@]}" --seed 1) &
(one R1 "${R1[@]}"; one R3 "${R3[@]}"; one S2 "${S2[@]}"; one S2-s2 "${S2[@]}" --seed 2; one B2 "${B2[@]}"; one B4 "${B4[@]}"; one B3-s2 "${B3[@]}" --seed 2; one B1-s2 "${B1[@]}" --seed 2) &
wait
