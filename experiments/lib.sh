# Shared by the experiment scripts (source it): the checkpoint naming of `tacgnn train-policy`.

# resume RUN_DIR: "--resume" when the run holds a checkpoint (a run stopped before its first
# one has only config.yaml, and --resume would refuse it)
resume() { compgen -G "$1/model_*.pt" >/dev/null && echo --resume || true; }
# last RUN_DIR ITERATIONS: the checkpoint written after that many iterations
last() { printf "%s/model_%06d.pt" "$1" "$2"; }
