#!/usr/bin/env bash
# The privileged route to a blind Baoding policy, trained for the Hard task (Table III, TacGNN rows).
#
#   experiments/table3_tacgnn.sh [SEED] [PERCEPTION_SET]
#
# 1. a ground-truth policy: the Simple-task policy (runs/gt_s0) fine-tuned on Hard (runs/gt_hard_s$SEED)
# 2. its rollouts as the perception dataset (50,000 frames, from the first step)
# 3. TacGNN-32 trained on it offline; PERCEPTION_SET adds model settings, e.g. "model.joint_inputs=16"
# 4. the policy fine-tuned with the perceived ball positions, perception trained in the loop
# 5. evaluation on Simple, Middle and Hard, 512 episodes each
# Every step skips what already exists and resumes a run that was cut off (datasets resume by themselves).
set -euo pipefail
cd "$(dirname "$0")/.."
SEED=${1:-0}
PSET=${2:-}
TAG=$( [ -n "$PSET" ] && echo "_joints" || echo "" )
T=.venv/bin/tacgnn
GT=runs/gt_hard_s$SEED
resume() { [ -f "$1/config.yaml" ] && echo --resume || true; }

if [ ! -f $GT/model_002000.pt ]; then
  $T train-policy --run-dir $GT $(resume $GT) --env tactile=false task=hard --ppo max_iterations=2000 \
    save_interval=100 init_from=runs/gt_s0/model_002500.pt init_noise_std=0.3 seed=$SEED
fi
DATA=data/baoding_gthard_s$SEED
$T make-dataset baoding --policy $GT/model_002000.pt --out $DATA --samples 50000 --settle-steps 0 --seed $SEED
PERC=runs/perc/gthard_s${SEED}_tacgnn32$TAG
if ! grep -q '"epoch": 9' $PERC/history.json 2>/dev/null; then
  $T train-perception --task baoding --model tacgnn --dataset $DATA --run $PERC --epochs 10 --seed $SEED \
    $( [ -f $PERC/checkpoint.pt ] && echo --resume || true ) --set match_balls=false $PSET
fi
RUN=runs/tacgnn${TAG}_hard_s$SEED
if [ ! -f $RUN/model_001200.pt ]; then
  $T train-policy --run-dir $RUN $(resume $RUN) --env obs_mode=perceived task=hard --ppo max_iterations=1200 \
    save_interval=100 init_from=$GT/model_002000.pt init_noise_std=0.2 learning_rate=0.0003 schedule=fixed \
    seed=$SEED --perception model.name=tacgnn pretrained=$PERC/checkpoint.pt match_balls=false epochs=2 \
    update_every_steps=400
fi
for ckpt in $GT/model_002000.pt $RUN/model_001200.pt; do
  out=results/$(basename $(dirname $ckpt))_$(basename $ckpt .pt).json
  [ -f $out ] || $T evaluate $ckpt --task all --episodes 512 --envs 128 --out $out
done
