#!/usr/bin/env bash
# The route to a blind Baoding policy on the torque-limited hand (Table III and the shipped policies).
#
#   experiments/baoding_pipeline.sh MODEL [SEED] [ITERATIONS]
#
#   MODEL       perception model: tacgnn, mlp, cnn or gcn; tacgnn-temporal or mlp-temporal for the model with
#               memory over time (docs/results.md section 6)
#   SEED        seed of the perception and the blind run (default 0); the teacher is shared (seed 0)
#   ITERATIONS  PPO iterations of the blind fine-tuning (default 1000)
#
# 1. teacher: a ground-truth policy trained on Simple (runs/gt_s0, 250 iterations: 100 % training success from about 150), fine-tuned on
#    the 'hold' task (Simple, then both balls in the hand 1 s: runs/gt_hold_s0, 300 iterations)
# 2. the teacher's rollouts as the perception dataset (50,000 frames from the first step)
# 3. the perception trained on them offline (10 epochs)
#    temporal models instead: 160,000 frames of the hold teacher's episodes, every step kept (seed 1),
#    and the temporal perception trained on them over windows (20 epochs); trained once (seed 0) and
#    shared by the blind runs of every SEED, as the teacher is
# 4. the blind policy: the teacher fine-tuned on 'hold' with the perceived ball positions (the
#    critic reads the true ones), the perception trained in the loop (2 epochs on the newest
#    25,600 frames every 400 env steps)
# 5. evaluation on Simple, Middle, Hard and the 1 s hold, 512 episodes each ->
#    results/table3/RUN_model_NNNNNN.json
# Every step skips what exists and resumes what was cut off, so the script can be rerun.
set -euo pipefail
cd "$(dirname "$0")/.."
MODEL=${1:?usage: experiments/baoding_pipeline.sh MODEL [SEED] [ITERATIONS]}
SEED=${2:-0}
ITERS=${3:-1000}
T=.venv/bin/tacgnn
source experiments/lib.sh  # resume, last, train_gt, perception_run, offline_perception, stage

stage teacher
GT_SIMPLE=runs/gt_s0
GT=runs/gt_hold_s0
train_gt $GT_SIMPLE 250 "" "" save_interval=50
train_gt $GT 300 "$(last $GT_SIMPLE 250)" task=hold \
  "save_interval=50 init_noise_std=0.3 learning_rate=0.0003 schedule=fixed"
stage perception data and training
case $MODEL in
  *-temporal)
    NAME=${MODEL%-temporal}
    DATA=data/baoding_seq2
    $T make-dataset baoding --policy "$(last $GT 300)" --out $DATA --samples 160000 --shard-size 10000 --seed 1 \
      --keep-every 1 --envs 16 --settle-steps 0 --set task=hold
    PERC=runs/perc/${NAME}_temporal
    perception_run $PERC 20 --dataset $DATA --temporal --model $NAME --window 32 --burn-in 200 \
      --set batch_size=16 lr_decay=0.85
    IN_LOOP="model.name=$NAME temporal=true" ;;
  *)
    DATA=data/baoding_teacher
    $T make-dataset baoding --policy "$(last $GT 300)" --out $DATA --samples 50000 --settle-steps 0 --seed 0
    PERC=runs/perc/${MODEL}_s$SEED
    offline_perception $PERC $MODEL $SEED $DATA
    IN_LOOP="model.name=$MODEL" ;;
esac
RUN=runs/blind_${MODEL/-/_}_s$SEED
stage blind policy
if [ ! -f "$(last $RUN $ITERS)" ]; then
  $T train-policy --run-dir $RUN $(resume $RUN) --env obs_mode=perceived task=hold --ppo max_iterations=$ITERS \
    save_interval=50 init_from="$(last $GT 300)" init_noise_std=0.2 learning_rate=0.0001 schedule=fixed \
    privileged_critic=true seed=$SEED \
    --perception $IN_LOOP pretrained=$PERC/checkpoint.pt epochs=2 update_every_steps=400
fi
stage evaluation
mkdir -p results/table3
for ckpt in "$(last $GT 300)" "$(last $RUN $ITERS)"; do
  out=results/table3/$(basename $(dirname $ckpt))_$(basename $ckpt .pt).json
  [ -f $out ] || $T evaluate $ckpt --task all --episodes 512 --envs 128 --out $out
done
stage done
