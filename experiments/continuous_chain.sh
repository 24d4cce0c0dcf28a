#!/usr/bin/env bash
# The counter-clockwise continuous ground-truth policies of docs/results.md section 7, from scratch:
# Simple (250 it.) -> canonical ball order (600) -> alive bonus, fall -200 (600) -> the long run
# (1,500) -> rotation weight 1.0 (1,800) -> rotation weight 1.5, smaller step and noise (300), each
# evaluated over 128 episodes of 10 s (results/continuous/; section 7 gives every stage of seeds 0 and 1).
#
#   experiments/continuous_chain.sh
#
# Environment: SETTINGS, env settings added to every stage (e.g. 'hand.target_ranges=[...]'), with
# TAG naming the runs runs/gt_TAG_s0, runs/gt_cont_canon_TAG_s0, ...; SEED, the training seed of
# every stage (default 0; the runs end in _sSEED).
# Every stage runs on the nominal hand without the action-rate and effort costs, as the chain was made
# (`randomization.enabled=false reward.action_rate=0 reward.effort=0`: train-policy's defaults are the hand
# of training and the gentle costs of section 11, under which the later stages drop balls in 10-70 %).
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
SEED=${SEED:-0}
# run NAME: the run directory of stage NAME
run() { echo runs/$1${TAG:+_$TAG}_s$SEED; }
NOMINAL="randomization.enabled=false reward.action_rate=0 reward.effort=0 ${SETTINGS:-}"
CONT="task=continuous ball_order=canonical $NOMINAL"
ALIVE="$CONT reward.alive=1.0 reward.fall=-200"
FINE="init_noise_std=0.3 learning_rate=0.0003 schedule=fixed seed=$SEED"
train_gt $(run gt) 250 "" "$NOMINAL" "save_interval=100 seed=$SEED"
stage $(run gt_cont_canon) 600 $(last $(run gt) 250) "$CONT" "$FINE"
stage $(run gt_cont_alive) 600 $(last $(run gt_cont_canon) 600) "$ALIVE" "$FINE"
stage $(run gt_cont_long) 1500 $(last $(run gt_cont_alive) 600) "$ALIVE" "$FINE"
stage $(run gt_cont_rot1) 1800 $(last $(run gt_cont_long) 1500) "$ALIVE reward.rotation=1.0" "$FINE"
stage $(run gt_cont_rot2) 300 $(last $(run gt_cont_rot1) 1800) "$ALIVE reward.rotation=1.5" \
  "init_noise_std=0.2 learning_rate=0.0001 schedule=fixed seed=$SEED"
