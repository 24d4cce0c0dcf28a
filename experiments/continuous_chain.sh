#!/usr/bin/env bash
# The counter-clockwise continuous ground-truth policies of docs/results.md section 7, from scratch:
# Simple (250 it.) -> canonical ball order (600) -> alive bonus, fall -200 (600) -> the long run
# (1,500) -> rotation weight 1.0 (1,800) -> rotation weight 1.5, smaller step and noise (300; the
# 9.0-turn policy), each evaluated over 128 episodes of 10 s (results/continuous/).
#
#   experiments/continuous_chain.sh
#
# Every stage skips what exists and resumes what was cut off, so the script can be rerun.
set -euo pipefail
cd "$(dirname "$0")/.."
T=.venv/bin/tacgnn
source experiments/lib.sh  # train_gt, last

# stage RUN ITERATIONS PARENT ENV_SETTINGS PPO_SETTINGS: train_gt (a checkpoint every 100
# iterations), then 128 episodes of 10 s
stage() {
  train_gt "$1" "$2" "$3" "$4" "save_interval=100 $5"
  local out=results/continuous/$(basename $1)_$(basename "$(last $1 $2)" .pt).json
  [ -f $out ] || $T evaluate "$(last $1 $2)" --task continuous --episodes 128 --out $out
}
CONT="task=continuous ball_order=canonical"
ALIVE="$CONT reward.alive=1.0 reward.fall=-200"
FINE="init_noise_std=0.3 learning_rate=0.0003 schedule=fixed"
train_gt runs/gt_s0 250 "" "" save_interval=100
stage runs/gt_cont_canon_s0 600 runs/gt_s0/model_000250.pt "$CONT" "$FINE"
stage runs/gt_cont_alive_s0 600 runs/gt_cont_canon_s0/model_000600.pt "$ALIVE" "$FINE"
stage runs/gt_cont_long_s0 1500 runs/gt_cont_alive_s0/model_000600.pt "$ALIVE" "$FINE"
stage runs/gt_cont_rot1_s0 1800 runs/gt_cont_long_s0/model_001500.pt "$ALIVE reward.rotation=1.0" "$FINE"
stage runs/gt_cont_rot2_s0 300 runs/gt_cont_rot1_s0/model_001800.pt "$ALIVE reward.rotation=1.5" \
  "init_noise_std=0.2 learning_rate=0.0001 schedule=fixed"
