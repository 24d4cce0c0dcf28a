"""The blind controller through a real ROS 1 master, the simulator as the hand: success, latency, missed ticks.

Starts a roscore on a free loopback port, `tacgnn real-hand sim-hand` (the hand) and
`tacgnn real-hand run` (the controller) as separate processes, both under `nice -n NICE`
(default -10: above jobs at nice >= 0; negative values need root), waits for the hand's
episodes (or `--minutes`) and prints the hand's success rate, the command lags the hand
saw, the loop's tick-to-command latency and missed ticks. With `--reference` it first
runs the same episodes (same env, seed, calibration path) with the controller called in
the same process, no ROS and no clock: what the ROS loop must reproduce.

    .venv/bin/python bench/bench_ros.py --episodes 64 --reference
    .venv/bin/python bench/bench_ros.py --minutes 10 --out results/ros_10min.json
    .venv/bin/python bench/bench_ros.py --episodes 64 --hand-args="--latency-ms 20 --drop-tactile 0.05"
    .venv/bin/python bench/bench_ros.py --minutes 1 --stage-timers   # where the controller's tick spends its time

Needs ROS 1 (`make test-ros` installs Debian's ROS 1 and links rospy into the venv).
"""
from __future__ import annotations

import argparse
import json
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np

from tacgnn.files import atomic_write_text
from tacgnn.real.loopback_master import free_port, loopback_env, start_roscore, stop_roscore
from tacgnn.user_errors import run_script

if TYPE_CHECKING:
    from tacgnn.envs.baoding import BaodingConfig
    from tacgnn.real.sim_hand import SimHand


def busy_processes(seconds: float = 2.0, min_cpu: float = 10.0) -> list[dict]:
    """Processes using more than `min_cpu` % of a core over `seconds` (the load a run competes with)."""
    def sample() -> dict[int, tuple[int, int]]:
        out = {}
        for stat in Path("/proc").glob("[0-9]*/stat"):
            try:
                fields = stat.read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            out[int(stat.parent.name)] = (int(fields[11]) + int(fields[12]), int(fields[16]))  # utime+stime, nice
        return out

    before = sample()
    time.sleep(seconds)
    after = sample()
    hz = os.sysconf("SC_CLK_TCK")
    busy = []
    for pid, (ticks, nice) in after.items():
        cpu = 100.0 * (ticks - before.get(pid, (ticks, 0))[0]) / hz / seconds
        if cpu >= min_cpu:
            try:
                cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            except OSError:
                cmd = "?"
            busy.append({"cpu_percent": round(cpu), "nice": nice, "command": cmd.strip()[:160]})
    return sorted(busy, key=lambda p: -p["cpu_percent"])


def make_calibration(folder: Path, policy: str) -> Path:
    """The calibration `calibrate-skin` finds for the simulated hand's skin at rest (balls away)."""
    from tacgnn.learning.policy import load_policy
    from tacgnn.real.ros_config import RosConfig
    from tacgnn.real.sim_hand import SimHand, SimHandConfig
    from tacgnn.real.skin import calibrate

    env_config = load_policy(policy)[1]
    hand = SimHand(env_config, SimHandConfig(), RosConfig())
    hand.balls_away()
    rest = np.stack([hand.raw_skin(stepped=False) for _ in range(50)])
    return calibrate(rest, env_config.skin).save(folder / "calibration.npz")


def reference(policy: str, calibration: Path, task: Literal["simple", "middle", "hard"], episodes: int, seed: int,
              env_change: Callable[[BaodingConfig], BaodingConfig] | None = None,
              on_episode: Callable[[SimHand, bool], None] | None = None) -> dict:
    """The same episodes with the controller in this process, no ROS: each command applied at the next step.

    `env_change` edits the policy's env config for the simulated hand and the skin processor (e.g. a
    skin whose baseline does not track); `on_episode(hand, success)` is called as each episode ends."""
    import torch

    from tacgnn.envs.observation import target_to_action
    from tacgnn.real.controller import BlindController, BlindControllerConfig
    from tacgnn.real.ros_config import RosConfig
    from tacgnn.real.sim_hand import SimHand, SimHandConfig
    from tacgnn.real.skin import SkinCalibration, SkinProcessor

    torch.set_num_threads(1)
    controller = BlindController(BlindControllerConfig(policy=policy))
    env_config = controller.env_config if env_change is None else env_change(controller.env_config)
    processor = SkinProcessor.for_env(SkinCalibration.load(calibration), env_config)
    hand = SimHand(env_config, SimHandConfig(task=task, episodes=episodes, seed=seed), RosConfig())
    env = hand.env
    env.reset(seed=seed)
    low, high = env.joint_low, env.joint_high
    stepped = False  # the skin of the state the env just stepped to, or of a fresh start
    controller.reset(env.joint_pos[0].copy())
    wins, ticks, done, started = 0, [], 0, time.monotonic()
    while done < episodes:
        began = time.perf_counter()
        skin = processor.process_raw(hand.raw_skin(stepped))
        target = controller.step(env.joint_pos[0].copy(), env.joint_vel[0].copy(), skin)
        ticks.append(time.perf_counter() - began)
        _, _, terminated, truncated, info = hand.step(target_to_action(target, low, high)[None])
        if terminated[0] or truncated[0]:
            wins += bool(info["success"][0])
            done += 1
            if on_episode is not None:
                on_episode(hand, bool(info["success"][0]))
            stepped = False
            controller.reset(env.joint_pos[0].copy())
        else:
            stepped = True
    ms = 1e3 * np.asarray(ticks[10:])  # the first ticks pay for lazy initialisation
    return {"episodes": episodes, "success_rate": wins / episodes, "seconds": round(time.monotonic() - started, 1),
            "tick_compute_ms": {"p50": round(float(np.percentile(ms, 50)), 3),
                                "p99": round(float(np.percentile(ms, 99)), 3)}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=64)
    parser.add_argument("--minutes", type=float, default=0.0, help="run this long instead (episodes unlimited)")
    parser.add_argument("--task", default="simple", choices=["simple", "middle", "hard"])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--policy", default="", help="default: the shipped blind policy")
    parser.add_argument("--nice", type=int, default=-10, help="niceness of the hand and controller processes")
    parser.add_argument("--hand-args", default="", help="extra sim-hand arguments, e.g. '--latency-ms 20'")
    parser.add_argument("--run-args", default="", help="extra real-hand run arguments")
    parser.add_argument("--reference", action="store_true", help="first run the same episodes without ROS")
    parser.add_argument("--stage-timers", action="store_true",
                        help="time each stage of the controller's tick (bench/stage_timers/sitecustomize.py)")
    parser.add_argument("--out", default="", help="write all figures as JSON here")
    args = parser.parse_args()
    if shutil.which("roscore") is None:
        sys.exit("bench_ros: roscore not found (make test-ros installs ROS 1)")
    from tacgnn.learning.policy import SHIPPED_POLICY

    policy = args.policy or str(SHIPPED_POLICY)
    work = Path(tempfile.mkdtemp(prefix="bench_ros_"))
    calibration = make_calibration(work, policy)
    result: dict = {"policy": policy, "task": args.task, "nice": args.nice, "hand_args": args.hand_args,
                    "load_average_start": os.getloadavg(), "busy_processes_start": busy_processes()}
    if args.reference and not args.minutes:
        result["reference"] = ref = reference(policy, calibration, args.task, args.episodes, args.seed)
        print(f"reference (no ROS, same episodes): success {ref['success_rate']:.3f} of {ref['episodes']}, "
              f"tick compute p50 {ref['tick_compute_ms']['p50']} ms, p99 {ref['tick_compute_ms']['p99']} ms")
    port = free_port()
    env = loopback_env(port, work)
    try:
        core = start_roscore(env, port)
    except RuntimeError as e:
        sys.exit(f"bench_ros: {e}")
    prefix = ["nice", "-n", str(args.nice)] if args.nice else []
    tacgnn = [*prefix, sys.executable, "-m", "tacgnn.cli", "real-hand"]
    episodes = 10**6 if args.minutes else args.episodes
    hand_cmd = [*tacgnn, "sim-hand", "--policy", policy, "--task", args.task, "--seed", str(args.seed),
                "--episodes", str(episodes), "--summary", str(work / "hand.json"), *shlex.split(args.hand_args)]
    if args.minutes:
        hand_cmd += ["--duration", str(60 * args.minutes)]
    run_env = dict(env)
    if args.stage_timers:
        timers = str(Path(__file__).resolve().parent / "stage_timers")
        run_env["PYTHONPATH"] = os.pathsep.join(p for p in (timers, env.get("PYTHONPATH", "")) if p)
        run_env["TACGNN_STAGE_TIMERS"] = str(work / "stages.json")
    run_cmd = [*tacgnn, "run", "--policy", policy, "--calibration", str(calibration), "--stats",
               str(work / "stats.json"), *shlex.split(args.run_args)]
    started = time.monotonic()
    try:
        with open(work / "hand.log", "w") as hand_log, open(work / "run.log", "w") as run_log:
            hand = subprocess.Popen(hand_cmd, env=env, stdout=hand_log, stderr=subprocess.STDOUT)
            time.sleep(0.5)
            ctrl = subprocess.Popen(run_cmd, env=run_env, stdout=run_log, stderr=subprocess.STDOUT)
            limit = 600 + (90 * args.minutes if args.minutes else 3 * args.episodes)
            ctrl.wait(limit)
            hand.wait(60)
    finally:
        for proc in ("hand", "ctrl"):
            p = locals().get(proc)
            if p is not None and p.poll() is None:
                p.kill()
                p.wait(10)
        stop_roscore(core)
    if hand.returncode or ctrl.returncode:
        print((work / "hand.log").read_text()[-2000:], (work / "run.log").read_text()[-2000:], sep="\n")
        sys.exit(f"bench_ros: hand exit {hand.returncode}, controller exit {ctrl.returncode} (logs in {work})")
    summary = json.loads((work / "hand.json").read_text())
    stats = json.loads((work / "stats.json").read_text())
    summary.pop("results")
    result.update(hand=summary, controller=stats, seconds=round(time.monotonic() - started, 1),
                  load_average_end=os.getloadavg(), busy_processes_end=busy_processes())
    if args.stage_timers:
        result["stages"] = stages = json.loads((work / "stages.json").read_text())
        print("  tick stages (ms, p50 / p99): " + "; ".join(
            f"{name} {ms['p50']} / {ms['p99']}" for name, ms in stages["stages_ms"].items()))
    lat = stats["tick_to_command_ms"]
    print(f"through ROS: {summary['episodes']} episodes, success {summary['success_rate']:.3f}, "
          f"{summary['steps']} steps in {summary['seconds']:.0f} s")
    print(f"  command lag at the hand (steps: count): {summary['command_lag_steps']}; "
          f"hand's state-to-command p50 {summary['response_ms']['p50']} ms, p99 {summary['response_ms']['p99']} ms")
    print(f"  controller: {stats['ticks']} ticks, {stats['commands']} commands, {stats['missed_ticks']} missed "
          f"({stats['held_stale']} held on stale data, {stats['overruns']} overruns), "
          f"{stats.get('unpaired_skin', 0)} with the skin of another instant")
    print(f"  tick-to-command p50 {lat['p50']} ms, p99 {lat['p99']} ms, max {lat['max']} ms; compute p50 "
          f"{stats['compute_ms']['p50']} ms, p99 {stats['compute_ms']['p99']} ms; load average "
          f"{result['load_average_start'][0]:.1f} -> {result['load_average_end'][0]:.1f}")
    for when in ("start", "end"):
        print(f"  busy processes at the {when}: " + "; ".join(
            f"{p['cpu_percent']}% nice {p['nice']} {p['command'][:70]}" for p in result[f"busy_processes_{when}"]))
    if args.out:
        from tacgnn.provenance import provenance

        result["provenance"] = provenance({"policy": policy}, args.seed, {k: v for k, v in vars(args).items()
                                                                         if k != "out"})
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(args.out, json.dumps(result, indent=1))
        print(f"wrote {args.out}")
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    raise SystemExit(run_script(main))
