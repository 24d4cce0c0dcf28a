#!/usr/bin/env bash
# How much does one PPO iteration of fine-tuning move a trained policy? The ground-truth Hard
# policy fine-tuned on its own task and its own (true) observations, so that nothing but the
# PPO step can change its success rate, for a few learning rates.
#
#   experiments/finetune_lr.sh [ITERATIONS]      (default 1; Simple, 512 episodes)
#
# -> runs/ft_lr_X, results/ft_lr_X_model_NNNNNN_simple.json; the starting policy itself:
#    results/gt_hard_s0_model_002000.json (experiments/table3.sh)
set -euo pipefail
cd "$(dirname "$0")/.."
ITERS=${1:-1}
T=.venv/bin/tacgnn
source experiments/lib.sh  # resume, last
for lr in 0.0003 0.0001 0.00003 adaptive; do
  run=runs/ft_lr_$lr
  if [ $lr = adaptive ]; then opts="learning_rate=0.0003 schedule=adaptive"; else opts="learning_rate=$lr schedule=fixed"; fi
  [ -f "$(last $run $ITERS)" ] || $T train-policy --run-dir $run $(resume $run) --env tactile=false task=hard \
    --ppo max_iterations=$ITERS save_interval=1 init_from=runs/gt_hard_s0/model_002000.pt init_noise_std=0.2 $opts
  out=results/ft_lr_${lr}_model_$(printf %06d $ITERS)_simple.json
  [ -f $out ] || $T evaluate "$(last $run $ITERS)" --task simple --episodes 512 --envs 128 --out $out
done
