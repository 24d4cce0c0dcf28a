#!/usr/bin/env bash
# Domain randomisation on vs off, from scratch on the Simple task with true ball positions,
# each evaluated on the nominal hand and on an "other hand" outside the randomisation ranges
# (stiffness x0.7, damping x1.5, 0.25 kg balls, friction x0.7), and on that change applied
# twice and three times: stand-ins for a real hand.
#
#   experiments/domain_randomisation.sh [ITERATIONS] [SEED]
#
# DR off is the ground-truth policy runs/gt_s$SEED (table3.sh trains it, 1,000 iterations);
# DR on is runs/dr_on_s$SEED, the same recipe with randomization.enabled=true. Both are
# evaluated at 1,000 iterations (equal training), DR on also at ITERATIONS (default 2000):
# results/dr_{off,on}_s$SEED_model_NNNNNN_{nominal,other_hand_x1,_x2,_x3}.json, 256 episodes each.
set -euo pipefail
cd "$(dirname "$0")/.."
ITERS=${1:-2000}
SEED=${2:-0}
T=.venv/bin/tacgnn
source experiments/lib.sh  # resume, last, other_hand
RUN=runs/dr_on_s$SEED
[ -f "$(last $RUN $ITERS)" ] || $T train-policy --run-dir $RUN $(resume $RUN) \
  --env tactile=false randomization.enabled=true --ppo max_iterations=$ITERS save_interval=100 seed=$SEED
NOMINAL="randomization.enabled=false"
evaluate() {  # evaluate TAG CHECKPOINT
  for hand in nominal other_hand_x1 other_hand_x2 other_hand_x3; do
    out=results/$1_$(basename $2 .pt)_$hand.json
    set_=$NOMINAL; [ $hand != nominal ] && set_="$NOMINAL $(other_hand ${hand#other_hand_x})"
    [ -f $out ] || $T evaluate $2 --task simple --episodes 256 --envs 128 --out $out --set $set_
  done
}
evaluate dr_off_s$SEED "$(last runs/gt_s$SEED 1000)"
evaluate dr_on_s$SEED "$(last $RUN 1000)"
evaluate dr_on_s$SEED "$(last $RUN $ITERS)"
