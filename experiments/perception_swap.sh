#!/usr/bin/env bash
# Perception and control judged apart: one policy, many perceptions (tacgnn evaluate --perception).
#
#   experiments/perception_swap.sh [offline|inloop|cross|all]
#
#   offline  the ground-truth policy (runs/gt_hard_s0, 2,000 iterations) run blind through each
#            perception trained offline on its rollouts (runs/perc/gthard_sK_MODEL_pi): which
#            perception is the better one for control, with no PPO training in between
#   inloop   the same policy through the perceptions that came out of blind runs at 600 iterations
#            (learning rate 1e-4, trained in the loop)
#   cross    blind policies with their perceptions exchanged (TacGNN <-> CNN, seed 1, 600 it.)
# 512 episodes per task -> results/swap_POLICY__PERCEPTION.json; missing inputs are skipped.
set -euo pipefail
cd "$(dirname "$0")/.."
WHAT=${1:-all}
T=.venv/bin/tacgnn
GT=runs/gt_hard_s0/model_002000.pt

swap() {  # swap POLICY_CKPT PERCEPTION_FILE NAME
  local out=results/swap_$3.json
  [ -f "$1" ] && [ -f "$2" ] || { echo "skip $3: missing $1 or $2"; return 0; }
  [ -f $out ] || $T evaluate "$1" --perception "$2" --task all --episodes 512 --envs 128 --out $out
}
if [ "$WHAT" = offline ] || [ "$WHAT" = all ]; then
  for p in runs/perc/gthard_s?_{tacgnn,cnn,gcn,mlp}_pi; do
    swap $GT $p/checkpoint.pt gt__$(basename $p)
  done
fi
if [ "$WHAT" = inloop ] || [ "$WHAT" = all ]; then
  for run in tacgnn_wu4_lr0.0001_hard_s1 tacgnn_wu4_lr0.0001_hard_s2 cnn_wu4_lr0.0001_hard_s1 \
             mlp_wu4_lr0.0001_hard_s0; do
    swap $GT runs/blind_$run/model_000600.pt gt__blind_${run}_model_000600
  done
fi
if [ "$WHAT" = cross ] || [ "$WHAT" = all ]; then
  A=runs/blind_tacgnn_wu4_lr0.0001_hard_s1/model_000600.pt
  B=runs/blind_cnn_wu4_lr0.0001_hard_s1/model_000600.pt
  swap $A $B tacgnn_s1_policy__cnn_s1_perception
  swap $B $A cnn_s1_policy__tacgnn_s1_perception
fi
