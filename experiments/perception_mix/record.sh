#!/usr/bin/env bash
# The perception data of docs/results.md section 6: every step kept, randomised hands, the real skin.
# Training mix (split by episode into train / validation / test): a ground-truth policy (teacher_hold) on
# the 1 s hold and on the continuous task, a Gaussian whole-hand teacher on Simple (its fast gait),
# two teachers of other seeds (experiments/perception_mix/teachers.sh: seed 3's on the hold, seed 2's
# nominal-hand Simple stage on Simple) and smooth random motion. Held out (never trained on): the
# scripted finger wave and another teacher (the nominal-hand teacher). Fresh frames of that
# teacher (another seed), of the teacher of the blind policy shipped before and of the shipped ground
# truth (the shipped blind policy's teacher) for the in-loop figures. About 6 minutes on 2 cores.
set -euo pipefail
cd "$(dirname "$0")/../.."
T=.venv/bin/tacgnn
GT=results/perception_mix/checkpoints/teacher_hold.pt  # a ground-truth policy on the hold (900 it.)
SHIPPED=results/real_hand/checkpoints/blind_teacher.pt  # the teacher of the blind policy shipped before
WIDE=results/perception_mix/checkpoints/teacher_wide.pt  # the ground truth shipped before the Beta pair
OTHER=results/real_hand/checkpoints/teacher_nominal_simple.pt
HOLD3=results/perception_mix/checkpoints/teacher_hold_s3.pt  # another seed's teacher, randomised hold (1,000 it.)
SIMPLE2=results/perception_mix/checkpoints/teacher_simple_s2.pt  # another seed's, nominal-hand Simple (300 it.)
ON="--keep-every 1 --envs 16 --settle-steps 0 --shard-size 10000"
$T make-dataset baoding --policy $GT --out data/mix_hold --samples 160000 --seed 1 $ON --set task=hold randomization.enabled=true
$T make-dataset baoding --policy $GT --out data/mix_cont --samples 80000 --seed 2 $ON --set task=continuous randomization.enabled=true
$T make-dataset baoding --policy $WIDE --out data/mix_simple --samples 80000 --seed 4 $ON --set task=simple randomization.enabled=true
$T make-dataset baoding --policy $HOLD3 --out data/mix_hold_s3 --samples 80000 --seed 5 $ON --set task=hold randomization.enabled=true
$T make-dataset baoding --policy $SIMPLE2 --out data/mix_simple_s2 --samples 80000 --seed 6 $ON --set task=simple randomization.enabled=true
$T make-dataset baoding --scripted random --out data/mix_random --samples 100000 --seed 3 $ON --set task=hold randomization.enabled=true
$T make-dataset baoding --scripted wave --out data/heldout_wave --samples 10000 --seed 7 $ON --set task=hold randomization.enabled=true
$T make-dataset baoding --policy $OTHER --out data/heldout_teacher --samples 10000 --seed 8 $ON --set task=hold randomization.enabled=true
$T make-dataset baoding --policy $SHIPPED --out data/fresh_shipped_teacher --samples 10000 --seed 9 $ON --set task=hold randomization.enabled=true
$T make-dataset baoding --policy $GT --out data/fresh_teacher --samples 10000 --seed 9 $ON --set task=hold randomization.enabled=true
$T make-dataset baoding --policy results/real_hand/checkpoints/gt_ppo.pt --out data/fresh_shipped_gt --samples 10000 --seed 9 $ON --set task=hold randomization.enabled=true
