"""Audit the hand's physics under a policy: torques, sinking, squeezing, spawns, the skin's share.

    .venv/bin/python experiments/faithful_hand/audit.py POLICY [--episodes 64] [--set key=value ...]
        [--out results/faithful_hand/audit_<name>.json]

Every physics substep of every env is read back (`mujoco.batch.Batch.get_data` then collision
detection), so the figures count what the solver saw, not only the control-step instants:
* torque: largest |actuator force| (N m) against `hand.torque_limit`;
* penetration: depth of every ball-link contact per ball and substep (p99 and max, mm);
* normal force: hand-ball contact normal forces (p99, max, N) and the median over steps with contact;
* skin share: taxel readings summed over the steps against the hand-ball normal force on the
  skinned links' covered areas;
* task: success, mean steps to success, rotation speed (deg/s) and the 1 s hold.
Spawn overlaps over 10,000 resets are counted with the env's own reset.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import asdict, replace
from pathlib import Path

import mujoco
import numpy as np

from tacgnn.config import override, parse_overrides
from tacgnn.envs.baoding import BaodingConfig, BaodingEnv
from tacgnn.files import atomic_write_text
from tacgnn.learning.policy import load_perception, load_policy
from tacgnn.provenance import provenance
from tacgnn.sim.tactile import TactileModel
from tacgnn.user_errors import run_script


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("policy")
    ap.add_argument("--episodes", type=int, default=64)
    ap.add_argument("--set", nargs="*", default=[])
    ap.add_argument("--resets", type=int, default=10000)
    ap.add_argument("--out")
    args = ap.parse_args(argv)
    policy, env_cfg = load_policy(args.policy)
    cfg = override(env_cfg, parse_overrides(args.set))
    perception = load_perception(args.policy) if cfg.obs_mode == "perceived" else None
    stats = audit(policy, cfg, args.episodes, perception)
    stats["spawn_overlaps"] = count_spawn_overlaps(cfg, args.resets)
    stats["policy"] = args.policy
    stats["provenance"] = provenance({"policy": args.policy}, 123, {"env": asdict(cfg), "episodes": args.episodes,
                                                                     "resets": args.resets})
    text = json.dumps(stats, indent=1)
    print(text)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(args.out, text)
    return 0


def audit(policy, cfg: BaodingConfig, episodes: int, perception=None) -> dict:
    cfg = replace(cfg, num_envs=episodes)
    env = BaodingEnv(cfg, perception=perception)
    m = env.model
    data = mujoco.MjData(m)
    ball_geoms = set(env.ball_geom.tolist())
    patch_of_body = {m.body(p.body).id: k for k, p in enumerate(cfg.skin.patches)}
    offsets = cfg.skin.offsets()
    quiet = TactileModel(replace(cfg.skin, noise=0.0), m)
    pen: list[float] = []
    forces: list[float] = []
    tmax = 0.0
    skinned_force, read_force = 0.0, 0.0
    per_contact: list[tuple] = []  # (patch type, force, activated taxels) of patches touched by one contact
    orig_step = env.sim.step

    def stepped(nstep: int) -> np.ndarray:
        nonlocal tmax, skinned_force, read_force
        bad = np.zeros(env.num_envs, bool)
        for _ in range(nstep):
            bad |= orig_step(1)
            tmax = max(tmax, float(np.abs(env.sim.actuator_force).max()))
            for i in np.flatnonzero(~done):
                env.sim.batch.get_data(int(i), data)
                mujoco.mj_forward(m, data)
                readings = quiet.readings(data.sensordata[None], data.xpos[None], data.xmat[None])[0]
                on_patch: dict[int, list[float]] = {}  # ball contact forces per skinned link
                mixed: set[int] = set()  # patches also pressed by another link
                for j in range(data.ncon):
                    c = data.contact[j]
                    g = (int(c.geom[0]), int(c.geom[1]))
                    if g[0] in ball_geoms and g[1] in ball_geoms:
                        continue  # ball on ball
                    f = np.zeros(6)
                    mujoco.mj_contactForce(m, data, j, f)
                    if g[0] not in ball_geoms and g[1] not in ball_geoms:  # link on link
                        mixed |= {patch_of_body[b] for b in (int(m.geom_bodyid[g[0]]), int(m.geom_bodyid[g[1]]))
                                  if b in patch_of_body}
                        continue
                    pen.append(-min(c.dist, 0.0))
                    forces.append(f[0])
                    link = g[1] if g[0] in ball_geoms else g[0]
                    k = patch_of_body.get(int(m.geom_bodyid[link]))
                    if k is not None:
                        on_patch.setdefault(k, []).append(f[0])
                for k, fs in on_patch.items():
                    if k in mixed:
                        continue
                    patch_read = float(readings[offsets[k]:offsets[k + 1]].sum())
                    skinned_force += sum(fs)
                    read_force += patch_read
                    if len(fs) == 1 and fs[0] > 0.05:
                        kind = cfg.skin.patches[k].name.split("_")[-1]
                        per_contact.append((kind, fs[0], int((readings[offsets[k]:offsets[k + 1]] > 0).sum())))
        return bad

    env.sim.step = stepped
    obs, _ = env.reset(seed=123)
    done = np.zeros(env.num_envs, bool)
    success = np.zeros(env.num_envs, bool)
    steps_to_success = np.zeros(env.num_envs)
    t0 = time.time()
    for _ in range(cfg.max_episode_steps):
        obs, _, term, trunc, info = env.step(policy(obs))
        newly = (term | trunc) & ~done
        success |= newly & info["success"]
        steps_to_success[newly & info["success"]] = info["episode_steps"][newly & info["success"]]
        done |= newly
        if done.all():
            break
    pen_mm = 1000 * np.asarray(pen)
    taxels = {}
    for kind in sorted({k for k, _, _ in per_contact}):
        rows = np.array([(f, n) for k, f, n in per_contact if k == kind])
        edges = [0.05, 0.5, 1, 2, 4, 8, 1e9]
        taxels[kind] = {"median_force": float(np.median(rows[:, 0])),
                        "median_taxels": float(np.median(rows[:, 1])),
                        "by_force": {f"{lo}-{hi}": float(np.median(rows[(rows[:, 0] >= lo) & (rows[:, 0] < hi), 1]))
                                     for lo, hi in zip(edges[:-1], edges[1:])
                                     if ((rows[:, 0] >= lo) & (rows[:, 0] < hi)).any()}}
    force_n = np.asarray(forces)
    return {
        "episodes": episodes,
        "torque_limit": cfg.hand.torque_limit,
        "max_actuator_torque": tmax,
        "penetration_mm_p99": float(np.percentile(pen_mm, 99)) if len(pen_mm) else 0.0,
        "penetration_mm_max": float(pen_mm.max()) if len(pen_mm) else 0.0,
        "ball_link_contacts": len(pen_mm),
        "normal_force_p99": float(np.percentile(force_n, 99)) if len(force_n) else 0.0,
        "normal_force_max": float(force_n.max()) if len(force_n) else 0.0,
        "normal_force_median": float(np.median(force_n)) if len(force_n) else 0.0,
        # taxel readings against the hand-ball normal force on skinned links pressed by balls only,
        # covered or not (contacts on a link's bare edges count against the skin)
        "skin_share_of_skinned_link_force": read_force / skinned_force if skinned_force else None,
        "taxels_per_contact": taxels,
        "success": float(success.mean()),
        "mean_steps_to_success": float(steps_to_success[success].mean()) if success.any() else None,
        "seconds": time.time() - t0,
    }


def count_spawn_overlaps(cfg: BaodingConfig, resets: int) -> dict:
    env = BaodingEnv(replace(cfg, num_envs=min(resets, 1000), obs_mode="groundtruth"))
    m, d = env.model, mujoco.MjData(env.model)
    balls = set(env.ball_geom.tolist())
    overlaps, worst, done = 0, 0.0, 0
    seed = 0
    while done < resets:
        env.reset(seed=seed)
        seed += 1
        for i in range(env.num_envs):
            d.qpos[:] = env.sim.qpos[i]
            mujoco.mj_kinematics(m, d)
            mujoco.mj_collision(m, d)
            dist = [d.contact.dist[j] for j in range(d.ncon) if balls & set(d.contact.geom[j].tolist())]
            if dist and min(dist) < 0:
                overlaps += 1
                worst = min(worst, min(dist))
        done += env.num_envs
    return {"resets": done, "overlapping": overlaps, "deepest_mm": -1000 * worst}


if __name__ == "__main__":
    raise SystemExit(run_script(main))
