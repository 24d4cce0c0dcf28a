#!/usr/bin/env bash
# Why does TacGNN carry over to the other hand best? One of its two differences from the MLP and
# the CNN, taken away: TacGNN-32 with the raw force in N as its node feature instead of
# log(f / 1 N) (model.force_feature=raw). Heavier balls press harder; the log turns that into a
# shift that an edge's difference g(f_j) - g(f_i) cancels, the raw force does not. The other
# difference, that TacGNN reads where the activated taxels are, stays.
#
#   experiments/force_input.sh [SEEDS...]        (default: 0 1 2)
#
# For each seed: TacGNN-32 with raw force trained offline on the teacher's rollouts (as
# experiments/table3.sh step 3, 10 epochs) -> runs/perc/gthard_sK_tacgnnraw_pi; then the teacher
# runs blind through it on the nominal hand (512 episodes per task, as experiments/perception_swap.sh
# offline) and on the other hand (256, as experiments/other_hand.sh 600 1). The tables:
#    .venv/bin/python experiments/perception_swap_report.py
#    .venv/bin/python experiments/perception_swap_report.py --condition otherhand_x1
set -euo pipefail
cd "$(dirname "$0")/.."
T=.venv/bin/tacgnn
source experiments/lib.sh  # other_hand
GT=runs/gt_hard_s0/model_002000.pt
DATA=data/baoding_gthard_s0
SEEDS=("$@"); [ ${#SEEDS[@]} -gt 0 ] || SEEDS=(0 1 2)
[ -f $GT ] && [ -d $DATA ] || { echo "missing $GT or $DATA: run WARMUP=4 GT_SEED=0 experiments/table3.sh tacgnn 0 first"; exit 1; }
for seed in "${SEEDS[@]}"; do
  PERC=runs/perc/gthard_s${seed}_tacgnnraw_pi
  if ! grep -q '"epoch": 9' $PERC/history.json 2>/dev/null; then
    $T train-perception --task baoding --model tacgnn --dataset $DATA --run $PERC --epochs 10 --seed $seed \
      $( [ -f $PERC/checkpoint.pt ] && echo --resume || true ) --set model.force_feature=raw
  fi
  out=results/swap_gt__$(basename $PERC).json
  [ -f $out ] || $T evaluate $GT --perception $PERC/checkpoint.pt --task all --episodes 512 --envs 128 --out $out
  out=results/otherhand_x1_swap_gt__$(basename $PERC).json
  [ -f $out ] || $T evaluate $GT --perception $PERC/checkpoint.pt --task all --episodes 256 --envs 128 --out $out \
    --set $(other_hand 1)
done
