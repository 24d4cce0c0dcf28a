#!/usr/bin/env bash
# The shipped policies, made on the hand as uncertain as a real one (randomised physics, motors and
# encoders; the real skin and its calibration) and with gentle fingers, then their robustness tables.
#
#   experiments/real_hand/pipeline.sh [SEED] [BLIND_ITERATIONS]
#
# 1. teacher (true ball positions, no skin): 300 iterations on the nominal hand (the route known to
#    learn from scratch), 800 on the randomised hand, 600 on the 1 s hold task with the gentle costs
#    (squeeze above 3 N, its tail above 6 N, action rate, effort)
# 2. 160,000 frames of the teacher's episodes on randomised hands and the real skin, every step kept
# 3. the temporal TacGNN trained on them over windows (20 epochs)
# 4. the blind policy: the teacher fine-tuned with the perceived ball positions on the hold task, on
#    randomised hands and the real skin, the perception trained in the loop
# 5. robustness tables of both -> results/real_hand/{gt,blind}_robustness.{json,md}
# Every step skips what exists and resumes what was cut off, so the script can be rerun.
set -euo pipefail
cd "$(dirname "$0")/../.."
SEED=${1:-0}
ITERS=${2:-400}
T=.venv/bin/tacgnn
source experiments/lib.sh  # resume, last, train_gt, perception_run, stage
GENTLE="reward.squeeze=-0.2 reward.squeeze_free_force=3.0 reward.squeeze_peak=true reward.squeeze_tail=-1.0 \
reward.squeeze_tail_force=6.0 reward.action_rate=-0.005 reward.effort=-0.02"
FINE="init_noise_std=0.3 learning_rate=0.0003 schedule=fixed"

stage teacher
train_gt runs/real_gt_nominal 300 "" randomization.enabled=false save_interval=50
train_gt runs/real_gt 800 "$(last runs/real_gt_nominal 300)" "" \
  "save_interval=50 init_noise_std=0.5 learning_rate=0.0005 schedule=fixed"
train_gt runs/real_gt_hold 600 "$(last runs/real_gt 800)" "task=hold $GENTLE" "save_interval=50 $FINE"
TEACHER=$(last runs/real_gt_hold 600)

stage perception data and training
DATA=data/real_seq
$T make-dataset baoding --policy "$TEACHER" --out $DATA --samples 160000 --shard-size 10000 --seed 1 \
  --keep-every 1 --envs 16 --settle-steps 0 --set task=hold randomization.enabled=true
PERC=runs/perc/real_tacgnn_temporal
perception_run $PERC 20 --dataset $DATA --temporal --model tacgnn --window 32 --burn-in 200 \
  --set batch_size=16 lr_decay=0.85

stage blind policy
RUN=runs/real_blind_s$SEED
if [ ! -f "$(last $RUN $ITERS)" ]; then
  $T train-policy --run-dir $RUN $(resume $RUN) --env obs_mode=perceived task=hold $GENTLE \
    --ppo max_iterations=$ITERS save_interval=50 init_from="$TEACHER" init_noise_std=0.2 learning_rate=0.0001 \
    schedule=fixed privileged_critic=true seed=$SEED \
    --perception model.name=tacgnn temporal=true pretrained=$PERC/checkpoint.pt epochs=2 update_every_steps=400
fi

stage robustness tables
mkdir -p results/real_hand
[ -f results/real_hand/gt_robustness.json ] || $T robustness "$TEACHER" --out results/real_hand/gt_robustness.json
[ -f results/real_hand/blind_s${SEED}_robustness.json ] || \
  $T robustness "$(last $RUN $ITERS)" --out results/real_hand/blind_s${SEED}_robustness.json
stage done
