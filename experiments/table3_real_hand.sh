#!/usr/bin/env bash
# Table III on the hand of the shipped policies: blind policies with each perception in the loop, on
# randomised hands and the real skin (docs/results.md section 2).
#
#   experiments/table3_real_hand.sh MODEL [SEED]
#
#   MODEL   perception model: tacgnn, mlp, cnn or gcn (single frame, the paper's four)
#   SEED    seed of the perception and of the blind run (default 0)
#
# The recipe of the shipped blind policy (experiments/real_hand/pipeline.sh step 3), with the paper's
# single-frame perceptions instead of the temporal one and without its random-motion anchor:
# 1. teacher: the shipped blind policy's teacher (TEACHER, default runs/real_gt/hold_slow/model_000500.pt,
#    made by `TEACHER_ONLY=1 experiments/real_hand/pipeline.sh`; its actor is
#    results/real_hand/checkpoints/blind_teacher.pt)
# 2. its 50,000 frames on randomised hands with the real skin (shared by every MODEL and SEED)
# 3. the perception trained on them offline (10 epochs)
# 4. the blind policy: the teacher fine-tuned on the hold with the perceived ball positions on the hands
#    of the shipped blind policy (400 it.; the critic reads the true positions), the perception trained
#    in the loop (2 epochs on the newest 25,600 frames every 400 env steps)
# 5. exported (results/table3_real_hand/checkpoints/, the perception inside) and evaluated on "a real
#    hand" (randomisation at its defaults, evaluation seed 0), 512 episodes per task ->
#    results/table3_real_hand/blind_MODEL_sSEED_model_000400.json
# Every step skips what exists and resumes what was cut off, so the script can be rerun.
set -euo pipefail
cd "$(dirname "$0")/.."
MODEL=${1:?usage: experiments/table3_real_hand.sh MODEL [SEED]}
SEED=${2:-0}
ITERS=400
TEACHER=${TEACHER:-runs/real_gt/hold_slow/model_000500.pt}
T=.venv/bin/tacgnn
source experiments/lib.sh  # resume, last, offline_perception, stage, SOFT, WIDE, REAL_HAND
[ -f "$TEACHER" ] || { echo "teacher $TEACHER not found: make it with TEACHER_ONLY=1 experiments/real_hand/pipeline.sh" >&2; exit 2; }
OUT=results/table3_real_hand
stage teacher frames
DATA=data/real_hand_teacher
$T make-dataset baoding --policy "$TEACHER" --out $DATA --samples 50000 --settle-steps 0 --seed 0 \
  --set randomization.enabled=true $WIDE
stage perception
PERC=runs/perc/real_hand_${MODEL}_s$SEED
offline_perception $PERC $MODEL $SEED $DATA
stage blind policy
RUN=runs/real_hand_blind_${MODEL}_s$SEED
if [ ! -f "$(last $RUN $ITERS)" ]; then
  $T train-policy --run-dir $RUN $(resume $RUN) --env obs_mode=perceived task=hold $SOFT $WIDE \
    --ppo max_iterations=$ITERS save_interval=50 init_from="$TEACHER" action_distribution=beta \
    learning_rate=0.0001 schedule=fixed privileged_critic=true seed=$SEED \
    --perception model.name=$MODEL pretrained=$PERC/checkpoint.pt epochs=2 update_every_steps=400
fi
stage evaluation
mkdir -p $OUT/checkpoints
POLICY=$OUT/checkpoints/blind_${MODEL}_s$SEED.pt
[ -f $POLICY ] || $T export-policy "$(last $RUN $ITERS)" --out $POLICY
RESULT=$OUT/blind_${MODEL}_s${SEED}_model_$(printf %06d $ITERS).json
[ -f $RESULT ] || $T evaluate $POLICY --task all --episodes 512 --envs 128 --seed 0 --out $RESULT --set $REAL_HAND
TEACHER_RESULT=$OUT/teacher_model_000500.json  # the committed actor of the default TEACHER
[ -f $TEACHER_RESULT ] || $T evaluate results/real_hand/checkpoints/blind_teacher.pt --task all --episodes 512 \
  --envs 128 --seed 0 --out $TEACHER_RESULT --set $REAL_HAND
stage done
