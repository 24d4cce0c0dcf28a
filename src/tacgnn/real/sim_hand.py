"""The simulator playing the real hand over ROS 1: the Allegro driver's topics, the Baoding task.

`tacgnn real-hand sim-hand` runs one Baoding env in real time and speaks the driver's
part: joint states at the control rate on the joint-state topic, one skin message per
control step (one raw array per patch), joint commands in. Each control period, at the
period's boundary, it applies the newest command (or holds the last one), steps the env
one control step and publishes what the hand then measures: the skin frame, then the
joint state, both stamped with the same instant: state k (the k-th state published)
k control periods after the start, so the stamp names the step. A command's stamp names
the state it answers, so the hand counts how late each command is: lag 0 (the state
just published, what the env does), 1 (a period late), ...
Episodes end as in the env (success, a ball falling, timeout); the env resets, the new
episode number goes out on the episode topic at once and the new episode's first state
one period later (a reset takes a period, so the controller has the number before the
state), and `tacgnn real-hand run` restarts its episode as the env would; commands that
answer a state of an earlier episode are ignored. After the last episode it publishes -1
(the controller stops) and writes a summary (success rate as `tacgnn evaluate` counts
it, the command lags, the hand's state-to-command response times).

What a real hand adds is on by default: 20 ms of transport latency, and the real skin
(`tacgnn.sim.skin_signal`: noise floor, offsets, drift, crosstalk, saturation, dead and
stuck taxels), sent as the raw values its driver would report, so that the controller sees
only what `tacgnn calibrate-skin` makes of them, as on a real hand. Dropped joint-state or
skin messages and noise on the joint angles can be switched on. With ``skin: ideal`` the
skin is sent as ``skin_baseline + readings``.
"""

from __future__ import annotations

import heapq
import json
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from tacgnn.config import check, check_seed
from tacgnn.envs.baoding import BaodingConfig, BaodingEnv
from tacgnn.envs.observation import target_to_action
from tacgnn.files import atomic_write_text
from tacgnn.real.messages import decode_joint_state, stamp_ns, tactile_message_class
from tacgnn.real.node import RosNode
from tacgnn.real.ros_config import RosConfig

log = logging.getLogger("tacgnn.real")


@dataclass(frozen=True)
class SimHandConfig:
    task: Literal["simple", "middle", "hard"] = "simple"
    episodes: int = 64
    seed: int = 0
    latency_s: float = 0.02
    """Delay of every message the hand sends (joint states, skin)."""
    skin: Literal["real", "ideal"] = "real"
    """The skin's signal chain (`BaodingConfig.skin_signal.preset`), whatever the policy trained on."""
    drop_tactile: float = 0.0
    """Probability that a skin message is lost."""
    drop_joint_states: float = 0.0
    stray_joint_states: float = 0.0
    """Probability that a malformed joint state (NaN angles, as from a faulty node on the same
    topic) follows a step's joint state: the controller must drop it and go on."""
    joint_noise_rad: float = 0.0
    """Std of Gaussian noise on the published joint angles."""
    skin_baseline: float = 10.0
    """Raw value of an untouched taxel of the ideal skin."""
    rest_steps: int = 0
    """If > 0: hold the start pose with no balls for this many steps first (skin at rest, for
    `record-skin` and `calibrate-skin`), then stop without running episodes."""
    start_delay_s: float = 1.0
    """Least time (s) the start state is published before the first step; the first step also
    waits for the first command."""
    wait_for_controller_s: float = 120.0
    """Give up when no command came within this time."""
    duration_s: float = 0.0
    """If > 0, stop after this many seconds (after the step in progress), even before `episodes`."""

    def __post_init__(self) -> None:
        check_seed(self.seed)
        check(self.task in ("simple", "middle", "hard"), "task", f"must be simple, middle or hard, got {self.task!r}")
        check(self.episodes >= 1, "episodes", "must be >= 1")
        check(self.latency_s >= 0, "latency_s", "must be >= 0")
        check(self.latency_s <= 10, "latency_s", f"must be <= 10 s, got {self.latency_s}")
        check(self.skin in ("real", "ideal"), "skin", f"must be 'real' or 'ideal', got {self.skin!r}")
        for name in ("drop_tactile", "drop_joint_states", "stray_joint_states"):
            check(0 <= getattr(self, name) < 1, name, "must be in [0, 1)")
        check(0 <= self.joint_noise_rad <= 1, "joint_noise_rad", "must be in [0, 1] rad")
        check(0 < self.skin_baseline <= 1e6, "skin_baseline", "must be in (0, 1e6]")
        check(self.duration_s >= 0, "duration_s", "must be >= 0 (0: no limit)")


class DelayedPublisher:
    """Publishes callables' messages `latency_s` after they are handed over, from one thread."""

    def __init__(self, latency_s: float):
        self.latency = latency_s
        self._queue: list[tuple[float, int, Callable[[Any], None], Any]] = []
        self._count = 0
        self._wake = threading.Condition()
        self._closed = False
        if latency_s > 0:
            threading.Thread(target=self._run, daemon=True).start()

    def __call__(self, publish: Callable[[Any], None], msg: Any) -> None:
        if self.latency <= 0:
            publish(msg)
            return
        with self._wake:
            heapq.heappush(self._queue, (time.monotonic() + self.latency, self._count, publish, msg))
            self._count += 1
            self._wake.notify()

    def _run(self) -> None:
        while True:
            with self._wake:
                while not self._closed and (not self._queue or self._queue[0][0] > time.monotonic()):
                    self._wake.wait(None if not self._queue else max(0.0, self._queue[0][0] - time.monotonic()))
                if self._closed:
                    return
                _, _, publish, msg = heapq.heappop(self._queue)
            publish(msg)

    def close(self) -> None:
        with self._wake:
            self._closed = True
            self._wake.notify()


class SimHand:
    """One Baoding env behind the Allegro driver's topics (see the module docstring)."""

    def __init__(self, env_config: BaodingConfig, cfg: SimHandConfig, ros: RosConfig):
        self.cfg, self.ros = cfg, ros
        env_cfg = replace(env_config, num_envs=1, task=cfg.task, seed=cfg.seed, obs_mode="groundtruth", tactile=True,
                          skin_signal=replace(env_config.skin_signal, preset=cfg.skin))
        self.env = BaodingEnv(env_cfg)
        self.rng = np.random.default_rng(cfg.seed + 1)
        self.layout = env_cfg.skin
        self.offsets = self.layout.offsets()
        fields = dict(ros.tactile_fields)
        missing = [p.name for p in self.layout.patches if p.name not in fields]
        if missing:
            raise ValueError(f"ros.tactile_fields has no field for patches {missing}")
        self.fields = [fields[p.name] for p in self.layout.patches]
        self.results: list[dict] = []

    def step(self, action: np.ndarray):
        """`env.step` of one hand with one skin: a real hand keeps its skin (offsets, gains, dead
        taxels, drift) from episode to episode, where the env draws a new one at each reset; so the
        skin as it was carries over an episode's end, and one calibration serves the session."""
        skin = self.env.skin_signal.state_dict()
        out = self.env.step(action)
        if out[2][0] or out[3][0]:
            self.env.skin_signal.load_state_dict(skin)
        return out

    def balls_away(self) -> None:
        """Put the balls far from the hand: the skin at rest, as a calibration records it."""
        env = self.env
        for b, x in zip(env.ball_qpos_adr, (0.0, 0.3)):
            env.sim.qpos[0, b:b + 3] = (x, 0.0, -1.0)
        env.sim.forward()

    def raw_skin(self, stepped: bool) -> np.ndarray:
        """(T,) the driver's raw values of the skin now: of the frame the env's step just took
        (`stepped`), or a new frame of the hand as it stands."""
        env = self.env
        if self.cfg.skin == "ideal":
            return (self.cfg.skin_baseline + env.tactile_readings()[0]).astype(np.float32)
        raw = env.skin_signal.last_raw if stepped else env.raw_skin()
        return np.asarray(raw[0], np.float32)

    def run(self, summary_path: str | Path | None = None) -> dict:
        cfg, ros, env = self.cfg, self.ros, self.env
        node = RosNode(ros, "tacgnn_sim_hand")
        tactile_cls = tactile_message_class(ros)
        skin_stamped = "header" in getattr(tactile_cls, "__slots__", ())
        pub_joints = node.publisher(ros.joint_state_topic, node.JointState)
        pub_skin = node.publisher(ros.tactile_topic, tactile_cls)
        pub_episode = node.publisher(ros.episode_topic, node.Int32, latch=True) if ros.episode_topic else None
        period = ros.period
        period_ns = int(round(period * 1e9))
        base_ns = time.time_ns()  # ROS time of state 0; state k is stamped base_ns + k periods
        published: list[float] = []  # monotonic time at which state k was handed to the publisher
        command: dict[str, Any] = {"target": None, "count": 0, "answers": -1}
        response_s: list[float] = []

        def on_command(msg):
            now = time.monotonic()
            stamp = stamp_ns(msg)
            k = -1 if stamp is None else int(round((stamp - base_ns) / period_ns))
            command["target"], command["answers"] = decode_joint_state(msg, ros.joint_names)[0], k
            command["count"] += 1
            if 0 <= k < len(published):
                response_s.append(now - published[k])

        node.subscribe(ros.joint_cmd_topic, node.JointState, on_command, queue_size=10)  # count every command
        send = DelayedPublisher(cfg.latency_s)
        low, high = env.joint_low, env.joint_high

        def publish_state(stepped: bool) -> None:
            """The skin frame, then the joint state of state k = len(published), both stamped k."""
            stamp = base_ns + len(published) * period_ns
            published.append(time.monotonic())
            raw = self.raw_skin(stepped)
            if self.rng.random() >= cfg.drop_tactile:
                msg = tactile_cls()
                if skin_stamped:
                    node.set_stamp(msg, stamp)
                for i, attr in enumerate(self.fields):
                    setattr(msg, attr, raw[self.offsets[i]:self.offsets[i + 1]].tolist())
                send(pub_skin, msg)
            q = env.joint_pos[0] + cfg.joint_noise_rad * self.rng.standard_normal(16) if cfg.joint_noise_rad \
                else env.joint_pos[0]
            if self.rng.random() >= cfg.drop_joint_states:
                send(pub_joints, node.joint_state(q, env.joint_vel[0], stamp=stamp))
            if cfg.stray_joint_states and self.rng.random() < cfg.stray_joint_states:
                send(pub_joints, node.joint_state(np.full_like(q, np.nan), stamp=stamp))

        obs, _ = env.reset(seed=cfg.seed)
        if cfg.rest_steps:
            self.balls_away()
        episode = 0
        hold = env.last_action[0].copy()
        next_time = time.monotonic()
        warmup = max(1, int(round(cfg.start_delay_s / period)))
        steps = late = 0
        lags: dict[str, int] = {}
        t_start = time.monotonic()
        end = t_start + cfg.duration_s if cfg.duration_s > 0 else np.inf

        def tick_wait() -> None:
            nonlocal next_time, late
            delay = next_time - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            elif -delay > period:
                late += 1
            next_time += period

        def start_episode() -> int:
            """The episode's number now, its first state at the next period boundary; returns that state's index."""
            if pub_episode is not None:
                send(pub_episode, node.Int32(data=episode))
            tick_wait()
            publish_state(stepped=False)
            return len(published) - 1

        try:
            for _ in range(cfg.rest_steps):
                tick_wait()
                publish_state(stepped=False)
            waited = 0  # the start pose, until a controller commands (at least `warmup` periods)
            while not cfg.rest_steps and node.ok() and (waited < warmup or command["count"] == 0):
                if waited * period > cfg.wait_for_controller_s:
                    raise TimeoutError(f"no joint command on {ros.joint_cmd_topic} within "
                                       f"{cfg.wait_for_controller_s:.0f} s: is the controller running?")
                tick_wait()
                publish_state(stepped=False)
                waited += 1
            first = start_episode() if not cfg.rest_steps and node.ok() else 0
            while node.ok() and not cfg.rest_steps:
                tick_wait()
                newest = len(published) - 1
                if command["target"] is not None and command["answers"] >= first:
                    lag = newest - command["answers"]
                    key = str(lag) if lag < 3 else "3+"
                    lags[key] = lags.get(key, 0) + 1
                    hold = target_to_action(np.clip(command["target"], low, high), low, high)
                else:
                    lags["none"] = lags.get("none", 0) + 1
                command["target"] = None
                obs, _, terminated, truncated, info = self.step(hold[None])
                steps += 1
                if not (terminated[0] or truncated[0]):
                    if time.monotonic() > end:
                        break
                    publish_state(stepped=True)
                    continue
                self.results.append({"episode": episode, "success": bool(info["success"][0]),
                                     "fall": bool(info["fall"][0]), "timeout": bool(info["timeout"][0]),
                                     "steps": int(info["episode_steps"][0]),
                                     "angle_deg": float(info["angle_deg"][0])})
                episode += 1
                if episode >= cfg.episodes or time.monotonic() > end:
                    break
                hold = env.last_action[0].copy()  # the env reset: its start pose
                first = start_episode()
        finally:
            if pub_episode is not None and node.ok():
                send(pub_episode, node.Int32(data=-1))
            time.sleep(0.5 + cfg.latency_s)
            send.close()
        summary = self.summary(steps, late, command["count"], time.monotonic() - t_start)
        summary["command_lag_steps"] = lags
        summary["response_ms"] = {q: round(1e3 * float(np.percentile(response_s, v)), 3) if response_s else None
                                  for q, v in (("p50", 50), ("p99", 99), ("max", 100))}
        if summary_path:
            Path(summary_path).parent.mkdir(parents=True, exist_ok=True)
            atomic_write_text(summary_path, json.dumps(summary, indent=1))
        node.shutdown("simulated hand done")
        return summary

    def summary(self, steps: int, late: int, commands: int, seconds: float) -> dict:
        n = len(self.results)
        wins = sum(r["success"] for r in self.results)
        return {"task": self.cfg.task, "episodes": n, "success_rate": wins / n if n else float("nan"),
                "fall_rate": sum(r["fall"] for r in self.results) / n if n else float("nan"),
                "steps": steps, "commands_received": commands, "late_steps": late, "seconds": round(seconds, 2),
                "latency_s": self.cfg.latency_s, "drop_tactile": self.cfg.drop_tactile,
                "drop_joint_states": self.cfg.drop_joint_states, "results": self.results}
