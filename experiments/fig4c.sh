#!/usr/bin/env bash
# Fig. 4C, the input ablations: PPO from scratch on the Simple task with another observation.
#
#   experiments/fig4c.sh MODE [ITERATIONS] [SEED]
#
#   MODE        obs_mode: groundtruth, no_perception, finger_torque, noise_2, noise_4 or noise_10
#   ITERATIONS  PPO iterations (default 1000)
#
# Trains runs/abl_MODE_sSEED (resumes it if cut off; the ground-truth input trains
# without the skin, as every mode here, since none of them reads it) and evaluates its last
# checkpoint on Simple, 256 episodes: results/fig4c/abl_MODE_sSEED_model_NNNNNN.json. The curves:
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
mkdir -p results/fig4c
out=results/fig4c/abl_${MODE}_s${SEED}_model_$(printf %06d $ITERS).json
[ -f $out ] || .venv/bin/tacgnn evaluate "$(last $RUN $ITERS)" --task simple --episodes 256 --envs 128 --out $out
