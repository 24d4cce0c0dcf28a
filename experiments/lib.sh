# Shared by the experiment scripts (source it): the checkpoint naming of `tacgnn train-policy`.

# resume RUN_DIR: "--resume" when the run holds a checkpoint (a run stopped before its first
# one has only config.yaml, and --resume would refuse it)
resume() { compgen -G "$1/model_*.pt" >/dev/null && echo --resume || true; }
# last RUN_DIR ITERATIONS: the checkpoint written after that many iterations
last() { printf "%s/model_%06d.pt" "$1" "$2"; }
# train_gt RUN ITERATIONS PARENT ENV_SETTINGS PPO_SETTINGS: a ground-truth policy (true ball
# positions, no skin) trained to ITERATIONS with seed $SEED (default 0; the env's and PPO's), starting
# from PARENT's networks ('' = from scratch); skipped when RUN has that checkpoint, resumed when it
# holds an earlier one
train_gt() {
  local run=$1 iters=$2 parent=$3 env=$4 ppo=$5
  [ -f "$(last $run $iters)" ] && return 0
  .venv/bin/tacgnn train-policy --run-dir $run $(resume $run) --env tactile=false seed=${SEED:-0} $env \
    --ppo max_iterations=$iters seed=${SEED:-0} $( [ -n "$parent" ] && echo init_from=$parent ) $ppo
}
# perception_run RUN EPOCHS ARG...: `tacgnn train-perception --run RUN --epochs EPOCHS ARG...`, skipped
# when RUN finished those epochs, resumed when RUN holds a checkpoint
perception_run() {
  local run=$1 epochs=$2; shift 2
  grep -q "\"epoch\": $((epochs - 1))" $run/history.json 2>/dev/null && return 0
  .venv/bin/tacgnn train-perception --run $run --epochs $epochs "$@" $( [ -f $run/checkpoint.pt ] && echo --resume || true )
}
# offline_perception RUN MODEL SEED DATASET [SETTING...]: train a Baoding perception for 10 epochs
# (perception_run); SETTINGs go to --set
offline_perception() {
  local run=$1 model=$2 seed=$3 data=$4; shift 4
  perception_run $run 10 --task baoding --model $model --dataset $data --seed $seed \
    $( [ $# -gt 0 ] && echo --set "$@" || true )
}
# other_hand K: the env changes of the "other hand" (a stand-in for a real hand), applied K times:
# K=1 is finger stiffness x0.7, damping x1.5, 0.25 kg balls instead of 0.15, ball and finger
# friction x0.7 (domain randomisation draws at most x0.8 / x1.2 / 0.2 kg / x0.8)
other_hand() {
  awk -v k=$1 'BEGIN { printf "hand.stiffness=%.4g hand.damping=%.4g ball_mass=%.4g ball_friction=%.4g hand.friction=%.4g", 3.0*0.7^k, 0.1*1.5^k, 0.15*(0.25/0.15)^k, 0.7^k, 0.7^k }'
}
# the real-hand recipe's soft costs (squeeze above 5 N, its tail above 8 N, action rate, effort) and its
# blind policy's hands (half of them drawn whole: docs/results.md section 11)
SOFT="reward.squeeze=-0.05 reward.squeeze_free_force=5.0 reward.squeeze_peak=true reward.squeeze_tail=-0.2 \
reward.squeeze_tail_force=8.0 reward.action_rate=-0.005 reward.effort=-0.02"
WIDE="randomization.joint_common=0.5"
# "a real hand" for evaluation: every range of the randomisation at its default, as `tacgnn robustness` draws it
REAL_HAND="randomization.enabled=true randomization.joint_common=0.0"
# stage NAME: a line on stderr with the seconds since the script started, to time each step
stage() { echo "[stage +${SECONDS}s] $*" >&2; }
