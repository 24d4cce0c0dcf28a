#!/usr/bin/env bash
# What in a perception's input makes it carry over to another hand, or fail in the loop? Each
# variant changes one input of one model:
#   tacgnnraw  TacGNN-32 with the raw force in N instead of log(f / 1 N) (model.force_feature=raw).
#              Heavier balls press harder; a log turns that into a shift (which TacGNN's edge
#              differences g(f_j) - g(f_i) cancel), the raw force does not.
#   mlplog     the MLP reading log(1 + f / 0.01 N) instead of f (model.reading_feature=log1p)
#   gcnrest    the GCN with each taxel's rest position as node input instead of its current one
#              (model.gcn_node_positions=rest): the nodes no longer carry the hand's pose
#
#   [VARIANTS="tacgnnraw mlplog gcnrest"] experiments/perception_inputs.sh [SEEDS...]   (default: 0 1 2)
#
# For each variant and seed: the perception trained offline on the teacher's rollouts (as
# experiments/table3.sh step 3, 10 epochs) -> runs/perc/gthard_sK_<variant>_pi; then the teacher
# runs blind through it on the nominal hand (512 episodes per task, as experiments/perception_swap.sh
# offline) and on the other hand (256, as experiments/other_hand.sh 600 1). The tables:
#    .venv/bin/python experiments/perception_swap_report.py
#    .venv/bin/python experiments/perception_swap_report.py --condition otherhand_x1
set -euo pipefail
cd "$(dirname "$0")/.."
T=.venv/bin/tacgnn
source experiments/lib.sh  # offline_perception, other_hand
GT=runs/gt_hard_s0/model_002000.pt
DATA=data/baoding_gthard_s0
SEEDS=("$@"); [ ${#SEEDS[@]} -gt 0 ] || SEEDS=(0 1 2)
[ -f $GT ] && [ -d $DATA ] || { echo "missing $GT or $DATA: run WARMUP=4 GT_SEED=0 experiments/table3.sh tacgnn 0 first"; exit 1; }
declare -A MODEL=([tacgnnraw]=tacgnn [mlplog]=mlp [gcnrest]=gcn)
declare -A SETTING=([tacgnnraw]=model.force_feature=raw [mlplog]=model.reading_feature=log1p
                    [gcnrest]=model.gcn_node_positions=rest)
for name in ${VARIANTS:-tacgnnraw mlplog gcnrest}; do
  [ -n "${MODEL[$name]:-}" ] || { echo "unknown variant $name (tacgnnraw, mlplog, gcnrest)"; exit 1; }
  model=${MODEL[$name]} setting=${SETTING[$name]}
  for seed in "${SEEDS[@]}"; do
    PERC=runs/perc/gthard_s${seed}_${name}_pi
    offline_perception $PERC $model $seed $DATA $setting
    out=results/swap_gt__$(basename $PERC).json
    [ -f $out ] || $T evaluate $GT --perception $PERC/checkpoint.pt --task all --episodes 512 --envs 128 --out $out
    out=results/otherhand_x1_swap_gt__$(basename $PERC).json
    [ -f $out ] || $T evaluate $GT --perception $PERC/checkpoint.pt --task all --episodes 256 --envs 128 --out $out \
      --set $(other_hand 1)
  done
done
