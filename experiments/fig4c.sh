#!/usr/bin/env bash
# Fig. 4C, the input ablations: PPO from scratch on the Simple task with another observation.
#
#   experiments/fig4c.sh MODE [ITERATIONS] [SEED]
#
#   MODE        obs_mode: groundtruth, no_perception, finger_torque, noise_2, noise_4 or noise_10
#   ITERATIONS  PPO iterations (default 1000)
#
# Trains runs/abl_MODE_sSEED (resumes it if cut off; the ground-truth input trains
# without the skin, as every mode here, since none of them reads it). The curves:
#   .venv/bin/python experiments/policy_curves.py OUT.png NOISE_2=runs/abl_noise_2_s0 ...
set -euo pipefail
cd "$(dirname "$0")/.."
MODE=${1:?usage: experiments/fig4c.sh MODE [ITERATIONS] [SEED]}
ITERS=${2:-1000}
SEED=${3:-0}
source experiments/lib.sh  # resume, last
RUN=runs/abl_${MODE}_s$SEED
[ -f "$(last $RUN $ITERS)" ] || .venv/bin/tacgnn train-policy --run-dir $RUN $(resume $RUN) \
  --env tactile=false obs_mode=$MODE --ppo max_iterations=$ITERS save_interval=100 seed=$SEED
