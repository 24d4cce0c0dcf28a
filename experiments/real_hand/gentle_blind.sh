#!/usr/bin/env bash
# The blind policy of the Beta teacher (experiments/real_hand/gentle_teacher.sh): the shipped blind
# policy's stage of experiments/real_hand/pipeline.sh from the Beta teacher's lower-rate hold
# (500 it.), with the perception pretrained on the six-controller mix (experiments/perception_mix/README.md).
#
#   experiments/real_hand/gentle_blind.sh [ITERATIONS] [PERCEPTION]  ->  runs/gentle_blind_s0
set -euo pipefail
cd "$(dirname "$0")/../.."
ITERS=${1:-400}
PERC=${2:-runs/perc/mix6_c32/best.pt}
source experiments/lib.sh  # resume, last, stage
SOFT="reward.squeeze=-0.05 reward.squeeze_free_force=5.0 reward.squeeze_peak=true reward.squeeze_tail=-0.2 \
reward.squeeze_tail_force=8.0 reward.action_rate=-0.005 reward.effort=-0.02"
RUN=runs/gentle_blind_s0
stage "Beta blind policy"
[ -f "$(last $RUN "$ITERS")" ] || .venv/bin/tacgnn train-policy --run-dir $RUN $(resume $RUN) \
  --env obs_mode=perceived task=hold $SOFT randomization.joint_common=0.5 \
  --ppo max_iterations=$ITERS save_interval=25 init_from="$(last runs/gentle_teacher_s0/hold_slow 500)" \
    action_distribution=beta learning_rate=0.0001 schedule=fixed privileged_critic=true seed=0 \
  --perception model.name=tacgnn temporal=true pretrained=$PERC epochs=2 update_every_steps=400 \
    anchor_dataset=data/mix_random anchor_share=0.25
stage done
