"""The `tacgnn` command line: one sub-command per user-facing job.

    tacgnn demo                      the shipped TacGNN policy on Simple: success rate and a video
    tacgnn render --out ep.mp4       video of an env (scripted, or --policy FILE) and a skin picture
    tacgnn view                      interactive MuJoCo viewer (needs a display)
    tacgnn config                    print the default Baoding config as YAML
    tacgnn make-dataset baoding --out data/baoding      skin frames + ball positions (HDF5 shards)
    tacgnn make-dataset grasp --object cube --out data/cube   power grasps + object poses
    tacgnn train-perception --task baoding --model tacgnn --dataset data/baoding --run runs/p1
    tacgnn eval-perception --checkpoint runs/p1/checkpoint.pt --dataset data/baoding [--dead 0.1] [--lose-patch palm]
    tacgnn train-policy --run-dir runs/gt --env obs_mode=groundtruth --ppo max_iterations=2000 [--resume]
    tacgnn evaluate runs/gt/model_002000.pt --task middle --episodes 500
    tacgnn sysid recording.npz --out outputs/sysid_hand.yaml    per-joint stiffness/damping from steps
    tacgnn sysid --make-recording rec.npz --random-truth        a simulated recording to try it on
    tacgnn calibrate-skin rest.npz --out skin_calibration.npz   real skin: baseline, thresholds, gains
    tacgnn real-hand run --calibration skin_calibration.npz     the blind policy on a real hand (ROS)

Config keys are dotted and checked before anything runs (an unknown key or a bad value is
one line): demo, render, view, config and make-dataset take ``--config FILE.yaml`` and
``--set key=value`` (e.g. ``--set task=middle sim.timestep=0.004``); train-perception,
sysid, real-hand and evaluate take ``--set``; train-policy takes ``--env``, ``--ppo`` and
``--perception``. A wrong file, key or value is reported in one line (exit code 2);
``--debug`` shows the traceback. Every command's ``--help`` lists its options with their defaults.
"""

import os

# Both are read once, when their library loads: set them before anything imports mujoco or torch.
# MuJoCo picks its OpenGL backend at import; the default (GLFW) needs a display, EGL renders
# offscreen anywhere. Idle OpenMP workers of torch's libgomp spin by default: with two jobs on a
# 2-core machine that made a 1-thread perception epoch 3-4x slower (15.7-17.1 s against 4.2-5.4 s
# with PASSIVE, same load).
os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from tacgnn.cli.app import build_parser, main  # noqa: E402

__all__ = ["build_parser", "main"]
