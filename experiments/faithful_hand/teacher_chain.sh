#!/usr/bin/env bash
# The ground-truth teachers of experiments/faithful_hand/README.md, from scratch: Simple (250 it.) -> the
# hold task (300) -> the gentler squeeze term (300) -> the squeeze charged on the peak force over
# substeps (300; the shipped teacher), then a longer, smaller-step fine-tune of the peak teacher.
#
#   experiments/faithful_hand/teacher_chain.sh [LONG_ITERATIONS]
#
# Every stage skips what exists and resumes what was cut off, so the script can be rerun.
set -euo pipefail
cd "$(dirname "$0")/../.."
LONG=${1:-1000}
TAIL_WEIGHT=${2:--1.0}
TAIL_FORCE=${3:-8.0}
source experiments/lib.sh  # train_gt

# stage RUN ITERATIONS PARENT ENV_SETTINGS PPO_SETTINGS: train_gt with a checkpoint every 50 iterations
stage() { train_gt "$1" "$2" "$3" "$4" "save_interval=50 $5"; }
FINE="init_noise_std=0.3 learning_rate=0.0003 schedule=fixed"
PEAK="reward.squeeze=-0.2 reward.squeeze_free_force=3.0 reward.squeeze_peak=true"
stage runs/gt_s0 250 "" "" ""
stage runs/gt_hold_s0 300 runs/gt_s0/model_000250.pt task=hold "$FINE"
stage runs/gt_hold_gentle_s0 300 runs/gt_hold_s0/model_000300.pt \
  "task=hold reward.squeeze=-0.2 reward.squeeze_free_force=2.0" "$FINE"
stage runs/gt_hold_soft_peak_s0 300 runs/gt_hold_gentle_s0/model_000300.pt "task=hold $PEAK" "$FINE"
stage runs/gt_hold_soft_peak_long_s0 $LONG runs/gt_hold_soft_peak_s0/model_000300.pt "task=hold $PEAK" \
  "init_noise_std=0.2 learning_rate=0.0001 schedule=fixed"
stage runs/gt_hold_soft_tail${TAIL_FORCE}_s0 $LONG runs/gt_hold_soft_peak_s0/model_000300.pt \
  "task=hold $PEAK reward.squeeze_tail=$TAIL_WEIGHT reward.squeeze_tail_force=$TAIL_FORCE" \
  "init_noise_std=0.2 learning_rate=0.0001 schedule=fixed"
