"""How hard a policy drives the fingers: actions at the ends of their range, joints at the torque limit.

    .venv/bin/python experiments/real_hand/gentleness.py POLICY [--episodes 128] [--set key=value ...]
        [--out results/real_hand/gentleness_NAME.json]

On the nominal hand (randomisation off, the policy's skin) and Simple unless `--set` says otherwise,
every control step of every episode until each env has finished one:
* actions at +-1: the share of finger actions (index, middle, ring: 12 joints) with |a| >= 0.999,
  and near it, |a| >= 0.95 (a policy whose mean cannot reach +-1, a Beta one, may still sit next to it);
* joint-steps at the torque limit: the share of finger joints whose actuator force is within 0.1 %
  of its limit, at every physics substep, and the share of those whose joint turns faster than
  1 rad/s (a stroke of the gait, not a grip held against a ball);
the thumb (nearly frozen in the Baoding task) is reported apart. The hand-ball force is the
faithful-hand audit's (`experiments/faithful_hand/audit.py`), which reads every contact.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace

import numpy as np

from tacgnn.config import override, parse_overrides
from tacgnn.envs.baoding import BaodingEnv
from tacgnn.files import atomic_write_text
from tacgnn.learning.policy import load_perception, load_policy
from tacgnn.provenance import provenance
from tacgnn.user_errors import run_script

FINGERS = slice(0, 12)
THUMB = slice(12, 16)


def measure(policy, cfg, episodes: int, perception=None) -> dict:
    env = BaodingEnv(replace(cfg, num_envs=episodes), perception=perception)
    limit = np.asarray(cfg.hand.joint_torque_limit())
    at_limit, moving, substeps = np.zeros(16), np.zeros(16), 0
    physics_step = env.sim.step

    def counted(nstep: int) -> np.ndarray:
        nonlocal substeps
        bad = np.zeros(env.num_envs, bool)
        for _ in range(nstep):
            bad |= physics_step(1)
            live = ~done
            pushing = np.abs(env.sim.actuator_force[live]) >= 0.999 * limit
            at_limit[:] += pushing.sum(0)
            moving[:] += (pushing & (np.abs(env.sim.qvel[live][:, env.joint_dof_adr]) > 1.0)).sum(0)
            substeps += int(live.sum())
        return bad

    env.sim.step = counted
    obs, _ = env.reset(seed=123)
    done = np.zeros(env.num_envs, bool)
    saturated, near_end, actions_seen = np.zeros(16), np.zeros(16), 0
    success = np.zeros(env.num_envs, bool)
    while not done.all():
        action = np.clip(policy(obs), -1, 1)
        saturated += (np.abs(action[~done]) >= 0.999).sum(0)
        near_end += (np.abs(action[~done]) >= 0.95).sum(0)
        actions_seen += int((~done).sum())
        obs, _, term, trunc, info = env.step(action)
        newly = (term | trunc) & ~done
        success |= newly & info["success"]
        done |= newly
    return {"episodes": episodes, "success": float(success.mean()),
            "finger_actions_at_limit": float(saturated[FINGERS].sum() / (12 * actions_seen)),
            "thumb_actions_at_limit": float(saturated[THUMB].sum() / (4 * actions_seen)),
            "finger_actions_beyond_0.95": float(near_end[FINGERS].sum() / (12 * actions_seen)),
            "finger_joint_steps_at_torque_limit": float(at_limit[FINGERS].sum() / (12 * substeps)),
            "of_those_moving_faster_than_1_rad_s": float(moving[FINGERS].sum() / max(at_limit[FINGERS].sum(), 1)),
            "thumb_joint_steps_at_torque_limit": float(at_limit[THUMB].sum() / (4 * substeps))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("policy")
    ap.add_argument("--episodes", type=int, default=128)
    ap.add_argument("--set", nargs="*", default=[], help="env config changes (default: the nominal hand, Simple)")
    ap.add_argument("--out")
    args = ap.parse_args(argv)
    policy, stored = load_policy(args.policy)
    cfg = override(stored, {"task": "simple", "randomization.enabled": False, **parse_overrides(args.set)})
    perception = load_perception(args.policy) if cfg.obs_mode == "perceived" else None
    stats = measure(policy, cfg, args.episodes, perception)
    print(json.dumps(stats, indent=1))
    if args.out:
        stats["provenance"] = provenance({"policy": args.policy}, 123, {"episodes": args.episodes, "set": args.set})
        atomic_write_text(args.out, json.dumps(stats, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(run_script(main))
