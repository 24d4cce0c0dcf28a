#!/usr/bin/env bash
# The blind TacGNN chain from a gentler teacher, as experiments/baoding_pipeline.sh builds it, with the
# squeeze charged on the peak force over substeps (reward.squeeze=-0.2 squeeze_free_force=3 squeeze_peak=true).
#
#   experiments/faithful_hand/soft_chain.sh [ITERATIONS] [TEACHER NAME [REWARD_SETTING...]]
#
# TEACHER defaults to the peak teacher (experiments/faithful_hand/teacher_chain.sh) and NAME to
# 'soft': data/baoding_teacher_NAME, runs/perc/tacgnn_NAME_s0, runs/blind_tacgnn_NAME_s0; the
# REWARD_SETTINGs are added to the blind run's reward (e.g. its teacher's squeeze_tail).
# Environment: PERCEPTION, more settings of the in-loop perception (e.g.
# "anchor_dataset=data/baoding_teacher"), with SUFFIX naming its run runs/blind_tacgnn_NAME_SUFFIX_s0;
# SEED, the blind run's seed (default 0; its run ends in _sSEED).
set -euo pipefail
cd "$(dirname "$0")/../.."
ITERS=${1:-400}
T=.venv/bin/tacgnn
source experiments/lib.sh  # resume, last, offline_perception
TEACHER=${2:-runs/gt_hold_soft_peak_s0/model_000300.pt}
NAME=${3:-soft}
REWARD="reward.squeeze=-0.2 reward.squeeze_free_force=3.0 reward.squeeze_peak=true ${*:4}"
DATA=data/baoding_teacher_$NAME
[ -f $DATA/manifest.json ] || $T make-dataset baoding --policy $TEACHER --out $DATA --samples 50000 --settle-steps 0 --seed 0
PERC=runs/perc/tacgnn_${NAME}_s0
offline_perception $PERC tacgnn 0 $DATA
SEED=${SEED:-0}
RUN=runs/blind_tacgnn_${NAME}${SUFFIX:+_$SUFFIX}_s$SEED
if [ ! -f "$(last $RUN $ITERS)" ]; then
  $T train-policy --run-dir $RUN $(resume $RUN) --env obs_mode=perceived task=hold $REWARD --ppo max_iterations=$ITERS \
    save_interval=50 init_from=$TEACHER init_noise_std=0.2 learning_rate=0.0001 schedule=fixed \
    privileged_critic=true seed=$SEED \
    --perception model.name=tacgnn pretrained=$PERC/checkpoint.pt epochs=2 update_every_steps=400 ${PERCEPTION:-}
fi
out=results/table3/$(basename $RUN)_$(basename "$(last $RUN $ITERS)" .pt).json
[ -f $out ] || $T evaluate "$(last $RUN $ITERS)" --task all --episodes 512 --envs 128 --out $out
