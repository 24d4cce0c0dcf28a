#!/usr/bin/env bash
# The shipped teacher's recipe (experiments/real_hand/pipeline.sh, stage 1) with a Beta policy
# (`action_distribution=beta`: the mean action stays inside the range, so the action-rate and effort
# costs can pull the fingers off their ends; a Gaussian's clipped mean cannot be pulled back): Simple
# on the nominal hand 300 it., the 1 s hold on the nominal hand 300, the hold on the randomised hand
# with the soft costs 400, at a lower rate 500, with half the hands drawn whole 500.
#
#   experiments/real_hand/gentle_teacher.sh [SEED]  ->  runs/gentle_teacher_sSEED/{simple,...,wide}
set -euo pipefail
cd "$(dirname "$0")/../.."
S=${1:-0}
source experiments/lib.sh  # resume, last, stage
SOFT="reward.squeeze=-0.05 reward.squeeze_free_force=5.0 reward.squeeze_peak=true reward.squeeze_tail=-0.2 \
reward.squeeze_tail_force=8.0 reward.action_rate=-0.005 reward.effort=-0.02"
FINE="learning_rate=0.0003 schedule=fixed"
SLOW="learning_rate=0.0001 schedule=fixed"
R=runs/gentle_teacher_s$S
teacher() {  # RUN ITERATIONS PARENT ENV_SETTINGS PPO_SETTINGS
  local run=$1 iters=$2 parent=$3 env=$4 ppo=$5
  [ -f "$(last $run $iters)" ] && return 0
  .venv/bin/tacgnn train-policy --run-dir $run $(resume $run) --env tactile=false seed=$S $env \
    --ppo max_iterations=$iters seed=$S save_interval=50 action_distribution=beta \
    $( [ -n "$parent" ] && echo init_from=$parent ) $ppo
}
stage "Beta teacher seed $S: Simple, nominal hand"
teacher $R/simple 300 "" randomization.enabled=false ""
stage "hold, nominal hand"
teacher $R/nominal_hold 300 "$(last $R/simple 300)" "task=hold randomization.enabled=false" "$FINE"
stage "hold, randomised hand"
teacher $R/hold 400 "$(last $R/nominal_hold 300)" "task=hold $SOFT" "$FINE"
stage "hold, randomised hand, lower rate"
teacher $R/hold_slow 500 "$(last $R/hold 400)" "task=hold $SOFT" "$SLOW"
stage "hold, half the hands drawn whole"
teacher $R/wide 500 "$(last $R/hold_slow 500)" "task=hold $SOFT randomization.joint_common=0.5" "$SLOW"
stage done
