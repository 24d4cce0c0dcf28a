"""Timers around each stage of the controller node's tick (`bench_ros.py --stage-timers`).

Python imports `sitecustomize` at start-up from the path; `bench_ros.py` puts this folder
first on PYTHONPATH and names the output in TACGNN_STAGE_TIMERS. Only the controller
process (`tacgnn real-hand run`) is instrumented: the tick's decoding, calibration,
kinematics, perception, policy and safety limits, and the publish; at exit it writes
percentiles per stage and the breakdown of the slowest ticks. Times are wall clock, so a
stage the scheduler interrupted carries the interruption.
"""
import atexit
import json
import os
import sys
import time

OUT = os.environ.get("TACGNN_STAGE_TIMERS")
if OUT and "real-hand" in sys.argv and "run" in sys.argv:
    import numpy as np

    from tacgnn.envs import observation
    from tacgnn.learning import online_perception
    from tacgnn.real import controller, kinematics, skin, tick

    clock = time.perf_counter
    ticks: list[dict[str, float]] = []
    current: dict[str, float] = {}

    def timed(owner, name: str, stage: str) -> None:
        fn = getattr(owner, name)

        def wrapper(*args, **kwargs):
            start = clock()
            try:
                return fn(*args, **kwargs)
            finally:
                current[stage] = current.get(stage, 0.0) + clock() - start
        setattr(owner, name, wrapper)

    tick_call = tick.ControlTick.__call__

    def timed_tick(self):
        current.clear()
        current["_start"] = start = clock()
        out = tick_call(self)
        current["tick_body"] = clock() - start
        return out
    tick.ControlTick.__call__ = timed_tick  # type: ignore[method-assign]
    timed(tick, "decode_joint_state", "decode_joint_state")
    timed(tick, "decode_tactile", "decode_skin")
    timed(skin.SkinProcessor, "__call__", "skin_calibration")
    timed(kinematics.TaxelKinematics, "positions", "kinematics")
    timed(online_perception.OnlinePerception, "__call__", "perception_network")
    timed(observation, "perceive_balls", "perception_with_tracking")
    timed(controller.BlindController, "act", "policy")
    timed(controller.BlindController, "limit", "safety_limits")
    import rospy

    publish = rospy.Publisher.publish

    def timed_publish(self, *args, **kwargs):
        start = clock()
        out = publish(self, *args, **kwargs)
        if "_start" in current and self.name.endswith("joint_cmd"):
            done = clock()
            current["publish"] = done - start
            current["tick_start_to_published"] = done - current["_start"]
            ticks.append({k: v for k, v in current.items() if not k.startswith("_")})
        return out
    rospy.Publisher.publish = timed_publish

    def write() -> None:
        kept = ticks[50:]  # the first ticks pay for lazy initialisation
        if not kept:
            return
        stages = sorted({k for t in kept for k in t})
        summary = {s: {f"p{q}": round(1e3 * float(np.percentile([t.get(s, 0.0) for t in kept], q)), 3)
                       for q in (50, 90, 99, 100)} for s in stages}
        slow = sorted(kept, key=lambda t: -t["tick_start_to_published"])[:20]
        assert OUT is not None  # set: this module only loads under TACGNN_STAGE_TIMERS
        with open(OUT, "w") as f:
            json.dump({"ticks": len(kept), "stages_ms": summary,
                       "slowest_ticks_ms": [{k: round(1e3 * v, 2) for k, v in t.items()} for t in slow]}, f, indent=1)
    atexit.register(write)
