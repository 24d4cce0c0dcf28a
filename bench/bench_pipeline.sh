#!/usr/bin/env bash
# The whole route to a blind Baoding policy, timed from a fresh clone (the target: 90 % on Simple
# within 3 h on 2 cores). Clones this repository's HEAD into a new folder, installs it there
# (`make install`, timed apart), runs experiments/baoding_pipeline.sh in it from nothing (teacher,
# data, perception, blind policy, evaluation) and prints each stage's wall time and the blind
# policy's success on each task.
#
#   bench/bench_pipeline.sh [MODEL] [SEED] [ITERATIONS] [FOLDER]
#
#   MODEL, SEED, ITERATIONS as for experiments/baoding_pipeline.sh (default tacgnn-temporal 0 400)
#   FOLDER      where to clone (default: a new temporary folder); kept afterwards, with the log
#               pipeline.log, so a cut-off bench resumes by running the pipeline there again
set -euo pipefail
MODEL=${1:-tacgnn-temporal}
SEED=${2:-0}
ITERS=${3:-400}
DIR=${4:-$(mktemp -d)}
ROOT=$(cd "$(dirname "$0")/.." && pwd)
RESULT=results/table3/blind_${MODEL/-/_}_s${SEED}_model_$(printf %06d "$ITERS").json  # the pipeline's naming
if [ ! -d "$DIR/.git" ]; then
  git clone --quiet "$ROOT" "$DIR"
  rm -f "$DIR/$RESULT"  # the repository's own figure for this run would be printed instead of this one's
fi
cd "$DIR"
start=$SECONDS
make install >/dev/null
echo "install: $((SECONDS - start)) s"
start=$SECONDS
experiments/baoding_pipeline.sh "$MODEL" "$SEED" "$ITERS" > pipeline.log 2>&1
echo "pipeline ($MODEL, seed $SEED, $ITERS it.): $((SECONDS - start)) s in $DIR"
grep '^\[stage ' pipeline.log
.venv/bin/python - "$RESULT" <<'PY'
import json
import sys

for row in json.load(open(sys.argv[1])):
    lo, hi = row["ci95"]
    print(f"{row['task']}: {100 * row['success_rate']:.1f} % ({100 * lo:.1f}-{100 * hi:.1f})")
PY
