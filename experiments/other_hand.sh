#!/usr/bin/env bash
# The blind policies of Table III on a hand they were not trained on: does the perception
# carry over? Each checkpoint experiments/table3.sh evaluated (learning rate 1e-4, warm-up
# rows) runs again with the "other hand" of experiments/domain_randomisation.sh applied K
# times (K=1: stiffness x0.7, damping x1.5, 0.25 kg balls instead of 0.15, ball and finger
# friction x0.7), 256 episodes per task. The heavier balls press the skin harder and the
# softer fingers sit elsewhere, so the skin's readings and the taxels' positions move away
# from everything the perception was trained on; the ground-truth teacher shows what the
# control alone loses. Then the teacher runs blind through each perception trained offline
# on its rollouts (as experiments/perception_swap.sh offline), on the same changed hand:
# the perceptions compared with the policy held fixed.
#
#   experiments/other_hand.sh [ITERATIONS] [K]      (defaults 600 and 1)
#   TEACHER_TAG=x (environment) the runs of a retrained teacher instead (experiments/table3.sh)
#
# -> results/otherhand_x$K_<run>_model_NNNNNN.json and results/otherhand_x$K_swap_gt__<perception>.json;
#    the tables:
#    .venv/bin/python experiments/table3_report.py --iterations 600 --condition otherhand_x1
#    .venv/bin/python experiments/perception_swap_report.py --condition otherhand_x1
set -euo pipefail
cd "$(dirname "$0")/.."
ITERS=${1:-600}
K=${2:-1}
T=.venv/bin/tacgnn
source experiments/lib.sh  # last, results_label, other_hand
SET=$(other_hand $K)
TT=${TEACHER_TAG:+_$TEACHER_TAG}
GT=runs/gt_hard_s0/model_002000.pt
runs=(runs/gt_hard_s0:2000)
for model in tacgnn tacgnn_joints cnn mlp gcn gcn_rest; do
  for run in runs/blind_${model}_wu4_lr0.0001${TT}_hard_s*; do
    [ -f "$(last $run $ITERS)" ] && runs+=("$run:$ITERS")
  done
done
for entry in "${runs[@]}"; do
  run=${entry%:*}; n=${entry#*:}
  out=results/otherhand_x${K}_$(results_label $run)_model_$(printf %06d $n).json
  [ -f $out ] || $T evaluate "$(last $run $n)" --task all --episodes 256 --envs 128 --out $out --set $SET
done
for p in runs/perc/gthard_s?_{tacgnn,cnn,gcn,gcn_rest,mlp}${TT}_pi; do
  out=results/otherhand_x${K}_swap_gt__$(basename $p).json
  if [ -f $p/checkpoint.pt ] && [ ! -f $out ]; then
    $T evaluate $GT --perception $p/checkpoint.pt --task all --episodes 256 --envs 128 --out $out --set $SET
  fi
done
