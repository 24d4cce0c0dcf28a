"""What sets the pace of the continuous Baoding turn: the hand's top joint speeds, and how a policy uses them.

    .venv/bin/python experiments/continuous_pace.py OUT.json LABEL=CHECKPOINT [...]
        [--episodes 64] [--seed 0] [--set KEY=VALUE ...] [--limits 0.5 100]

Two measurements, one JSON (with provenance):

* ``hand``: the bare hand (no balls, the env's hand config, stiffness and damping), one
  finger joint driven at a time by its position actuator while the others hold the task's
  start pose. A full-range step target gives the joint's top speed and the time to cover
  90 % of its range; a full-range square-wave target at 1-8 Hz gives the swing the joint
  still makes at that frequency (a gait of f strokes per second can use no more). Repeated
  for each actuator torque limit in `--limits` (0.5 N m is the task's; 100 stands for the
  old unlimited hand). The action maps straight onto the joint target (no per-step bound),
  so these are the hand's limits, not the env's. A policy's speed bounds below use the top
  speed of its own hand (its checkpoint's hand config, torque limit included).
* ``policies``: each checkpoint runs `--episodes` deterministic 10 s continuous-task episodes
  side by side (as `continuous_angle.py`), read back at every physics substep: the turn rate
  per second of the episode (mean over the episodes that keep both balls, and the fastest
  episode), how often each finger joint's actuator sits at its torque limit, its speeds
  against the hand's top speed, the swing and the main frequency of each joint (against the
  half-turn frequency: the canonical gait repeats every half turn), and how often the
  action sits at the end of its range.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from tacgnn.config import override, parse_overrides
from tacgnn.envs.baoding import BaodingConfig, BaodingEnv
from tacgnn.files import atomic_write_text
from tacgnn.hand.allegro import JOINT_NAMES
from tacgnn.learning.policy import load_perception, load_policy
from tacgnn.provenance import provenance
from tacgnn.sim.scene import hand_scene
from tacgnn.user_errors import labelled_paths, run_script

FINGER_JOINTS = 12  # index, middle, ring; the thumb is nearly frozen in the Baoding task
SQUARE_HZ = (1.0, 1.5, 2.0, 2.6, 3.0, 4.0, 5.0, 6.0, 8.0)
AT_LIMIT = 0.98  # |torque| >= this x the limit counts as at the limit


def hand_limits(cfg: BaodingConfig, torque_limit: float, joints: range) -> dict:
    """Top speed, time to 90 % of the range and square-wave swings of each joint in `joints`, bare hand."""
    hand = replace(cfg.hand, torque_limit=torque_limit)
    model = hand_scene(hand, cfg.sim).compile()
    data = mujoco.MjData(model)
    dt = model.opt.timestep
    start = np.clip(np.asarray(cfg.initial_joint_pos), *np.asarray(hand.joint_ranges).T)
    qadr, dadr = model.jnt_qposadr[:16], model.jnt_dofadr[:16]

    def settle(j: int, target: float) -> None:
        mujoco.mj_resetData(model, data)
        data.qpos[qadr] = start
        data.ctrl[:] = start
        data.qpos[qadr[j]] = data.ctrl[j] = target
        for _ in range(int(0.5 / dt)):
            mujoco.mj_step(model, data)

    out: dict[str, dict[str, Any]] = {}
    for j in joints:
        lo, hi = hand.joint_ranges[j]
        span = hi - lo
        step = {}
        for name, a, b in (("up", lo, hi), ("down", hi, lo)):
            settle(j, a)
            data.ctrl[j] = b
            speeds, reached = [], None
            for k in range(int(1.0 / dt)):
                mujoco.mj_step(model, data)
                speeds.append(abs(data.qvel[dadr[j]]))
                if reached is None and abs(data.qpos[qadr[j]] - a) >= 0.9 * span:
                    reached = (k + 1) * dt
            step[name] = {"top_speed_rad_s": float(max(speeds)), "time_to_90pct_s": reached,
                          "reached_rad": float(abs(data.qpos[qadr[j]] - a))}
        square = {}
        for hz in SQUARE_HZ:
            settle(j, lo)
            half = 0.5 / hz
            n = int(3.0 / dt)
            q, qd = np.empty(n), np.empty(n)
            for k in range(n):
                data.ctrl[j] = hi if (k * dt) % (2 * half) < half else lo
                mujoco.mj_step(model, data)
                q[k], qd[k] = data.qpos[qadr[j]], abs(data.qvel[dadr[j]])
            tail = slice(int(1.0 / dt), n)  # after a second, the steady swing
            swing = float(np.ptp(q[tail]))
            square[f"{hz:g} Hz"] = {"swing_rad": swing, "swing_of_range": swing / span,
                                    "top_speed_rad_s": float(qd[tail].max())}
        out[JOINT_NAMES[j]] = {"range_rad": span, "step": step, "square_wave": square}
    tops = [min(v["step"]["up"]["top_speed_rad_s"], v["step"]["down"]["top_speed_rad_s"]) for v in out.values()]
    return {"torque_limit_nm": torque_limit, "stiffness": hand.stiffness, "damping": hand.damping,
            "armature": hand.armature, "damping_bound_rad_s": torque_limit / float(np.max(hand.joint_damping())),
            "joints": out, "top_speed_min_over_joints_rad_s": float(min(tops))}


def rollout(checkpoint: str, episodes: int, seed: int, changes: dict) -> dict:
    """Per-substep joint speeds and actuator torques and per-step angles of `episodes` first episodes."""
    policy, stored = load_policy(checkpoint)
    cfg = override(replace(stored, task="continuous", num_envs=episodes, seed=seed), changes)
    perception = load_perception(checkpoint) if cfg.obs_mode == "perceived" else None
    env = BaodingEnv(cfg, perception=perception)
    n, limit = episodes, env.episode_limit
    torque_cap = np.asarray(cfg.hand.joint_torque_limit())
    sub = env.substeps
    qd = np.full((limit * sub, n, 16), np.nan)
    tau = np.full((limit * sub, n, 16), np.nan)
    q = np.full((limit, n, 16), np.nan)
    act = np.full((limit, n, 16), np.nan)
    angles = np.full((limit, n), np.nan)
    ended, fell = np.full(n, -1), np.zeros(n, bool)
    orig_step = env.sim.step
    t = 0

    def stepped(nstep: int) -> np.ndarray:
        bad = np.zeros(n, bool)
        for s in range(nstep):
            bad |= orig_step(1)
            live = ended < 0
            qd[t * sub + s, live] = env.joint_vel[live]
            tau[t * sub + s, live] = env.sim.actuator_force[live][:, :16]
        return bad

    env.sim.step = stepped
    obs, _ = env.reset(seed=seed)
    for t in range(limit):
        a = np.clip(policy(obs), -1, 1)
        live = ended < 0
        act[t, live] = a[live]
        obs, _, terminated, truncated, info = env.step(a)
        angles[t, live] = info["angle_deg"][live]
        q[t, live] = env.joint_pos[live]
        done = live & (terminated | truncated)
        fell[done] = info["fall"][done]
        ended[done] = t
    return {"config": cfg, "qd": qd, "tau": tau, "q": q, "act": act, "angles": angles, "ended": ended,
            "fell": fell, "torque_cap": torque_cap, "dt": cfg.control_dt}


def pace_summary(r: dict, top_speed: float) -> dict:
    """Turn rate over the episode, torque saturation, joint speeds, swings and frequencies of one rollout."""
    dt, angles, fell = r["dt"], r["angles"], r["fell"]
    steps_per_s = int(round(1 / dt))
    turns = np.array([a[~np.isnan(a)][-1] / 360 for a in angles.T])
    kept = ~fell
    # deg/s in each second of the episode (angle at the end of second k minus at its start)
    padded = np.vstack([np.zeros((1, angles.shape[1])), angles])
    ends = padded[steps_per_s::steps_per_s]
    per_second = np.diff(np.vstack([np.zeros((1, angles.shape[1])), ends]), axis=0)  # (10, N)
    best = int(np.nanargmax(np.where(kept, turns, -np.inf))) if kept.any() else int(np.argmax(turns))
    window = steps_per_s  # fastest 1 s of any episode
    fastest = np.nanmax(angles[window:] - angles[:-window])
    fingers = slice(0, FINGER_JOINTS)
    cap = r["torque_cap"][None, None, fingers]
    tau, qd = r["tau"][..., fingers], r["qd"][..., fingers]
    valid = ~np.isnan(tau[..., 0])
    at_cap = np.abs(tau) >= AT_LIMIT * cap
    speeds = np.abs(qd)[valid]  # (samples, 12)
    # the steady part of the kept episodes: after the first second
    steady = r["q"][steps_per_s:, kept][..., fingers]  # (T, K, 12)
    swing = np.ptp(steady, axis=0) if steady.size else np.zeros((0, FINGER_JOINTS))  # (K, 12)
    freqs = np.fft.rfftfreq(steady.shape[0], dt) if steady.size else np.zeros(0)
    spectrum = np.abs(np.fft.rfft(steady - steady.mean(0), axis=0)).mean(1) if steady.size else None  # (F, 12)
    main_hz = ([float(freqs[1:][np.argmax(spectrum[1:, j])]) for j in range(FINGER_JOINTS)]
               if spectrum is not None else [])
    turn_hz = float(np.mean(turns[kept]) / 10) if kept.any() else float("nan")
    a = np.abs(r["act"][..., fingers])
    a = a[~np.isnan(a[..., 0])]
    joints = {}
    for j in range(FINGER_JOINTS):
        joints[JOINT_NAMES[j]] = {
            "at_torque_limit": float(at_cap[..., j][valid].mean()),
            "speed_p50_p95_max_rad_s": [float(np.percentile(speeds[:, j], 50)), float(np.percentile(speeds[:, j], 95)),
                                        float(speeds[:, j].max())],
            "swing_rad_median": float(np.median(swing[:, j])) if len(swing) else None,
            "main_frequency_hz": main_hz[j] if main_hz else None,
            # strokes per second the hand allows this swing: out and back at the top speed
            "speed_bound_hz": float(top_speed / (2 * np.median(swing[:, j]))) if len(swing) else None,
            "action_at_end_of_range": float((a[:, j] >= 0.98).mean()),
        }
    return {
        "episodes": int(len(turns)), "falls": int(fell.sum()), "turns_mean": float(turns.mean()),
        "turns_kept_mean": float(turns[kept].mean()) if kept.any() else None,
        "turns_best": float(turns.max()),
        "deg_per_s_each_second_kept_mean": ([float(x) for x in np.nanmean(per_second[:, kept], 1)]
                                            if kept.any() else None),
        "deg_per_s_each_second_best_episode": [float(x) for x in per_second[:, best]],
        "fastest_1s_window_deg_per_s": float(fastest),
        "needed_for_13_turns_deg_per_s": 13 * 360 / 10,
        "half_turns_per_s_kept": 2 * turn_hz,
        "half_turns_per_s_for_13_turns": 2.6,
        "finger_joints_at_torque_limit": float(at_cap[valid].mean()),
        "finger_joints_at_torque_limit_any_joint": float(at_cap[valid].any(-1).mean()),
        "finger_speed_p95_rad_s": float(np.percentile(speeds, 95)),
        "finger_speed_max_rad_s": float(speeds.max()),
        "hand_top_speed_rad_s": top_speed,
        "finger_samples_above_80pct_top_speed": float((speeds >= 0.8 * top_speed).mean()),
        "finger_actions_at_end_of_range": float((a >= 0.98).mean()),
        # the largest median swing among the finger joints, and the stroke rate 2 x that swing allows
        "largest_swing_rad": float(np.max(np.median(swing, 0))) if len(swing) else None,
        "speed_bound_half_turns_per_s": (float(top_speed / (2 * np.max(np.median(swing, 0))))
                                         if len(swing) else None),
        "joints": joints,
    }


def fmt(value: float | None) -> str:
    """`value` to two decimals; 'n/a' where no episode gave it (every episode dropped a ball early)."""
    return "n/a" if value is None else f"{value:.2f}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", type=Path)
    parser.add_argument("policies", nargs="*", metavar="LABEL=CHECKPOINT")
    parser.add_argument("--episodes", type=int, default=64)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE")
    parser.add_argument("--limits", nargs="+", type=float, default=[0.5, 100.0], metavar="N_M",
                        help="actuator torque limits of the bare-hand test")
    args = parser.parse_args(argv)
    changes = parse_overrides(args.set)
    items = labelled_paths(args.policies)
    base = override(BaodingConfig(task="continuous", tactile=False), changes)
    hand = {f"{lim:g} N m": hand_limits(base, lim, range(FINGER_JOINTS)) for lim in args.limits}
    for name, h in hand.items():
        print(f"bare hand, {name}: top joint speed >= {h['top_speed_min_over_joints_rad_s']:.2f} rad/s "
              f"(limit / damping {h['damping_bound_rad_s']:.1f})")
        for joint, v in list(h["joints"].items())[4:8]:
            sq = ", ".join(f"{k} {s['swing_of_range']:.2f}" for k, s in v["square_wave"].items())
            print(f"  {joint}: up {v['step']['up']['top_speed_rad_s']:.2f} rad/s, 90 % in "
                  f"{v['step']['up']['time_to_90pct_s']} s; square-wave swing / range: {sq}")
    policies = {}
    own_top: dict[str, float] = {}  # the bare hand's top joint speed under each policy's own hand
    for label, ckpt in items:
        r = rollout(ckpt, args.episodes, args.seed, changes)
        cfg = r["config"]
        key = repr((cfg.hand, cfg.sim, cfg.initial_joint_pos))  # all that `hand_limits` reads of the config
        if key not in own_top:
            own_top[key] = hand_limits(cfg, cfg.hand.torque_limit,
                                       range(FINGER_JOINTS))["top_speed_min_over_joints_rad_s"]
        s = pace_summary(r, own_top[key])
        policies[label] = s
        print(f"{label}: {s['turns_mean']:.2f} turns ({s['falls']}/{s['episodes']} falls), fastest 1 s "
              f"{s['fastest_1s_window_deg_per_s']:.0f} deg/s; finger torques at the limit "
              f"{100 * s['finger_joints_at_torque_limit']:.1f} % "
              f"(any joint {100 * s['finger_joints_at_torque_limit_any_joint']:.1f} %); "
              f"speed p95 {s['finger_speed_p95_rad_s']:.2f}, max {s['finger_speed_max_rad_s']:.2f} rad/s; "
              f"actions at the end {100 * s['finger_actions_at_end_of_range']:.1f} %")
        print(f"  largest swing {fmt(s['largest_swing_rad'])} rad: the top speed allows "
              f"{fmt(s['speed_bound_half_turns_per_s'])} strokes/s; half turns/s {fmt(s['half_turns_per_s_kept'])}")
        print(f"  deg/s per second (kept): {np.round(s['deg_per_s_each_second_kept_mean'] or [], 0).tolist()}")
        for joint, v in s["joints"].items():
            print(f"  {joint}: at limit {100 * v['at_torque_limit']:.1f} %, "
                  f"speed {np.round(v['speed_p50_p95_max_rad_s'], 2).tolist()}, "
                  f"swing {fmt(v['swing_rad_median'])} rad, main {fmt(v['main_frequency_hz'])} Hz, "
                  f"speed bound {fmt(v['speed_bound_hz'])} Hz")
    record = {"hand": hand, "policies": policies,
              "provenance": provenance(dict(items), args.seed,
                                       {"episodes": args.episodes, "set": args.set, "limits": args.limits})}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(args.out, json.dumps(record, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(run_script(main))
