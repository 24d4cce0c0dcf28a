#!/usr/bin/env bash
# Independent ground-truth teachers for the perception mix: the first three stages of the teacher
# recipe (experiments/real_hand/pipeline.sh, with the authors' Gaussian actions: Simple on the nominal
# hand 300 it., the 1 s hold on the nominal hand 300, the hold on the randomised hand with the soft
# costs 400) from scratch with another seed, so that their grips owe nothing to the teachers already
# in the mix. About 25 minutes per seed on 2 cores (twice that with two seeds at once); seed 1 did
# not learn Simple in 300 it., seed 2's hold stage never held (its Simple stage is in the mix).
#
#   experiments/perception_mix/teachers.sh SEED   ->  runs/mix_teacher_sSEED/hold/model_000400.pt
set -euo pipefail
cd "$(dirname "$0")/../.."
S=${1:?usage: teachers.sh SEED}
export SEED=$S  # train_gt's seed
source experiments/lib.sh  # train_gt, last, stage, SOFT
FINE="save_interval=50 init_noise_std=0.3 learning_rate=0.0003 schedule=fixed"
R=runs/mix_teacher_s$S
stage "teacher seed $S: Simple, nominal hand"
train_gt $R/simple 300 "" randomization.enabled=false save_interval=50
stage "teacher seed $S: hold, nominal hand"
train_gt $R/nominal_hold 300 "$(last $R/simple 300)" "task=hold randomization.enabled=false" "$FINE"
stage "teacher seed $S: hold, randomised hand"
train_gt $R/hold 400 "$(last $R/nominal_hold 300)" "task=hold $SOFT" "$FINE"
stage done
