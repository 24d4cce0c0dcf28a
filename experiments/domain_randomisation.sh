#!/usr/bin/env bash
# Domain randomisation on vs off, from scratch on the Simple task with true ball positions,
# each evaluated on the nominal hand and on an "other hand" outside the randomisation ranges
# (stiffness x0.7, damping x1.5, 0.25 kg balls, friction x0.7), and on that change applied
# twice and three times: stand-ins for a real hand.
#
#   experiments/domain_randomisation.sh [ITERATIONS] [SEED]
#
# DR off is runs/dr_off_s$SEED, DR on runs/dr_on_s$SEED (the same recipe with
# randomization.enabled=true), both trained ITERATIONS (default 1000) and evaluated there:
# results/domain_randomisation/dr_{off,on}_s$SEED_model_NNNNNN_{nominal,other_hand_x1,_x2,_x3}.json,
# 256 episodes each.
set -euo pipefail
cd "$(dirname "$0")/.."
ITERS=${1:-1000}
SEED=${2:-0}
T=.venv/bin/tacgnn
source experiments/lib.sh  # resume, last, other_hand
for dr in off on; do
  RUN=runs/dr_${dr}_s$SEED
  [ -f "$(last $RUN $ITERS)" ] || $T train-policy --run-dir $RUN $(resume $RUN) \
    --env tactile=false randomization.enabled=$([ $dr = on ] && echo true || echo false) \
    --ppo max_iterations=$ITERS save_interval=100 seed=$SEED
done
NOMINAL="randomization.enabled=false"
evaluate() {  # evaluate TAG CHECKPOINT
  for hand in nominal other_hand_x1 other_hand_x2 other_hand_x3; do
    out=results/domain_randomisation/$1_$(basename $2 .pt)_$hand.json
    mkdir -p results/domain_randomisation
    set_=$NOMINAL; [ $hand != nominal ] && set_="$NOMINAL $(other_hand ${hand#other_hand_x})"
    [ -f $out ] || $T evaluate $2 --task simple --episodes 256 --envs 128 --out $out --set $set_
  done
}
evaluate dr_off_s$SEED "$(last runs/dr_off_s$SEED $ITERS)"
evaluate dr_on_s$SEED "$(last runs/dr_on_s$SEED $ITERS)"
