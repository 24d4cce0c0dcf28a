"""System identification of the hand's joint stiffness and damping from position steps.

The authors' method: per joint, try every pair of a grid of actuator stiffness kp and
joint damping (theirs: {1, 3, 5} x {0, 0.1, 0.5}), replay the recorded position commands
in simulation and keep the pair whose simulated joint angles are closest (L2) to the
recorded ones. Here the whole grid runs as one batch of simulations (`BatchedSim`, one
row per candidate), and the search is per joint:

1. pass 0: candidate c sets every joint to pair c; each joint takes its best pair.
2. refinement passes: the four joints of a finger are a coupled chain, and fingers can
   touch each other, so a joint's best pair can depend on what the other joints do. For
   each joint j and each candidate c, one simulation sets joint j to pair c and every
   other joint to its current best (16 x C simulations a pass); each joint re-picks with
   the others at their best. Repeat until nothing changes (usually one pass) or
   `refine_passes` is reached.

The error reported for a pair is the RMS (rad) over the recording of recorded minus
simulated angle of that joint, with the other joints at their identified values.

`make_recording` runs the same simulation with chosen "true" gains (and optional
measurement noise) to produce a recording, so the tool can be tried without hardware.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from tacgnn.config import check, to_dict
from tacgnn.files import atomic_write_text
from tacgnn.hand.allegro import JOINT_NAMES, NUM_JOINTS, HandConfig
from tacgnn.real.joint_recording import JointRecording
from tacgnn.sim.batched import BatchedSim
from tacgnn.sim.scene import SimConfig, hand_scene

JOINTS_PER_FINGER = 4


@dataclass(frozen=True)
class SysIdGrid:
    """Candidate values; every (stiffness, damping) pair is tried for every joint."""

    stiffness: tuple[float, ...] = (1.0, 3.0, 5.0)
    """Actuator gains kp (N m/rad) to try; the authors' grid."""
    damping: tuple[float, ...] = (0.0, 0.1, 0.5)
    """Joint dampings (N m s/rad) to try; the authors' grid."""

    def __post_init__(self) -> None:
        for name, ok, needs in (("stiffness", lambda v: v > 0, "> 0"), ("damping", lambda v: v >= 0, ">= 0")):
            values = getattr(self, name)
            check(len(values) >= 1, f"grid.{name}", "needs at least one value")
            check(all(np.isfinite(v) and ok(v) for v in values), f"grid.{name}",
                  f"every value must be finite and {needs}, got {list(values)}")
            check(len(set(values)) == len(values), f"grid.{name}", f"values repeat: {list(values)}")

    def candidates(self) -> np.ndarray:
        """(C, 2) pairs (stiffness, damping), stiffness-major: row i * len(damping) + j."""
        k, d = np.meshgrid(self.stiffness, self.damping, indexing="ij")
        return np.stack([k.ravel(), d.ravel()], axis=1).astype(np.float64)

    @staticmethod
    def linspace(stiffness: tuple[float, float], damping: tuple[float, float], n: int) -> SysIdGrid:
        """A finer grid: `n` evenly spaced values over each (low, high) range."""
        return SysIdGrid(tuple(np.linspace(*stiffness, n).round(6).tolist()),
                         tuple(np.linspace(*damping, n).round(6).tolist()))


@dataclass(frozen=True)
class StepProtocol:
    """The authors' excitation: every joint steps through `levels_deg`, each held `hold_steps`."""

    levels_deg: tuple[float, ...] = (0.0, 15.0, 30.0, 45.0, 60.0)
    """Absolute joint targets (deg), clipped to each joint's range."""
    hold_steps: int = 50
    """Control steps each level is held."""
    control_dt: float = 0.02
    """Control period (s): 50 Hz as on the Allegro hand."""
    sequential: bool = False
    """Step one joint at a time, the others held at the first level (16 x longer; the safe
    choice on a real hand, where flexed fingers can touch); False: all joints together."""

    def __post_init__(self) -> None:
        check(len(self.levels_deg) >= 2, "protocol.levels_deg", "needs at least two levels (a step)")
        check(self.hold_steps >= 1, "protocol.hold_steps", "must be >= 1")
        check(self.control_dt > 0, "protocol.control_dt", "must be positive")

    def targets(self, hand: HandConfig) -> np.ndarray:
        """(T, 16) joint targets (rad), clipped to the joint ranges."""
        lo, hi = np.asarray(hand.joint_ranges).T
        levels = np.deg2rad(np.repeat(np.asarray(self.levels_deg, np.float64), self.hold_steps))
        if not self.sequential:
            return np.clip(levels[:, None], lo, hi)
        blocks = []
        for j in range(NUM_JOINTS):
            block = np.full((len(levels), NUM_JOINTS), levels[0])
            block[:, j] = levels
            blocks.append(block)
        return np.clip(np.concatenate(blocks), lo, hi)


@dataclass(frozen=True)
class SysIdConfig:
    grid: SysIdGrid = field(default_factory=SysIdGrid)
    hand: HandConfig = field(default_factory=HandConfig)
    """The hand replayed: geometry, armature, full joint ranges. Its stiffness/damping are ignored."""
    sim: SimConfig = field(default_factory=lambda: SimConfig(nthread=1))
    refine_passes: int = 3
    """Passes with the other joints at their best (see module doc); 0: the plain grid pick."""

    def __post_init__(self) -> None:
        check(self.refine_passes >= 0, "refine_passes", f"must be >= 0, got {self.refine_passes}")


@dataclass(frozen=True, eq=False)
class SysIdResult:
    """Best pair per joint and the error of every candidate pair for every joint."""

    grid: SysIdGrid
    errors: np.ndarray
    """(C, 16) RMS error (rad) of candidate c on joint j, the other joints at their best
    (with refine_passes=0: every joint at candidate c)."""
    best: np.ndarray
    """(16,) index of each joint's best candidate."""
    passes: int
    """Simulation passes run (1 = pass 0 only)."""

    @property
    def stiffness(self) -> np.ndarray:
        return self.grid.candidates()[self.best, 0]

    @property
    def damping(self) -> np.ndarray:
        return self.grid.candidates()[self.best, 1]

    @property
    def best_errors(self) -> np.ndarray:
        return self.errors[self.best, np.arange(NUM_JOINTS)]

    def table(self, joint: int) -> np.ndarray:
        """Joint `joint`'s errors as a (len(stiffness), len(damping)) table."""
        return self.errors[:, joint].reshape(len(self.grid.stiffness), len(self.grid.damping))

    def hand_config(self, base: HandConfig) -> HandConfig:
        """`base` with the identified gains (scalars when all joints agree)."""
        def value(v: np.ndarray):
            return float(v[0]) if np.all(v == v[0]) else tuple(float(x) for x in v)
        return dataclasses.replace(base, stiffness=value(self.stiffness), damping=value(self.damping))


class StepReplay:
    """Simulates the hand under a target sequence, for a batch of per-joint gain settings."""

    PERIOD_TOLERANCE = 0.02
    """A measured control period within 2 % of a multiple of the physics step counts as that multiple."""

    def __init__(self, hand: HandConfig, sim: SimConfig, control_dt: float):
        substeps = max(1, round(control_dt / sim.timestep))
        if abs(substeps * sim.timestep - control_dt) > self.PERIOD_TOLERANCE * control_dt:
            raise ValueError(f"the recording's control period {control_dt:.6g} s is not a multiple of "
                             f"sim.timestep {sim.timestep} s; set sim.timestep to divide it")
        self.substeps = substeps
        self.hand, self.sim_cfg = hand, sim
        self.model = hand_scene(hand, sim).compile()
        self.qpos_adr = self.model.jnt_qposadr[:NUM_JOINTS].copy()
        self.dof_adr = self.model.jnt_dofadr[:NUM_JOINTS].copy()

    def run(self, target: np.ndarray, start: np.ndarray, stiffness: np.ndarray, damping: np.ndarray) -> np.ndarray:
        """(B, T, 16) joint angles: row b with gains stiffness[b], damping[b] (each (B, 16)).

        Starts at rest at `start`; sample t is taken just before target[t] is applied.
        A diverged simulation's angles are NaN from its divergence on.
        """
        n = len(stiffness)
        sim = BatchedSim(self.model, n, nthread=self.sim_cfg.nthread)
        sim.expand("actuator_gainprm")[:, :NUM_JOINTS, 0] = stiffness
        sim.expand("actuator_biasprm")[:, :NUM_JOINTS, 1] = -stiffness
        sim.expand("dof_damping")[:, self.dof_adr] = damping
        ids = np.arange(n)
        sim.reset(ids)
        qpos = sim.qpos.copy()
        qpos[:, self.qpos_adr] = start
        sim.qpos[:] = qpos
        sim.qvel[:] = 0.0
        sim.forward(ids)
        out = np.empty((n, len(target), NUM_JOINTS))
        out[:, 0] = sim.qpos[:, self.qpos_adr]
        alive = np.ones(n, bool)
        for t in range(len(target) - 1):
            sim.ctrl[:] = target[t]
            alive &= ~sim.step(self.substeps)
            out[:, t + 1] = np.where(alive[:, None], sim.qpos[:, self.qpos_adr], np.nan)
        return out


def _rms(sim: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """(B, 16) RMS over time of sim (B, T, 16) minus measured (T, 16); inf where diverged."""
    err = np.sqrt(np.mean((sim[:, 1:] - measured[1:]) ** 2, axis=1))
    return np.where(np.isfinite(err), err, np.inf)


def identify(rec: JointRecording, cfg: SysIdConfig | None = None) -> SysIdResult:
    """Best (stiffness, damping) of the grid for every joint of recording `rec`."""
    cfg = cfg or SysIdConfig()
    pairs = cfg.grid.candidates()
    c = len(pairs)
    replay = StepReplay(cfg.hand, cfg.sim, rec.period)
    start = rec.measured[0]

    # pass 0: candidate c on every joint at once
    sims = replay.run(rec.target, start, np.repeat(pairs[:, :1], NUM_JOINTS, 1), np.repeat(pairs[:, 1:], NUM_JOINTS, 1))
    errors = _rms(sims, rec.measured)
    best = errors.argmin(axis=0)
    passes = 1
    joints = np.arange(NUM_JOINTS)
    for _ in range(cfg.refine_passes):
        # simulation (j, c): joint j at candidate c, every other joint at its best (fingers can
        # touch each other, so no joint's simulation is shared with another's)
        gains = np.broadcast_to(pairs[best], (NUM_JOINTS, c, NUM_JOINTS, 2)).copy()
        gains[joints, :, joints] = pairs
        flat = gains.reshape(-1, NUM_JOINTS, 2)
        err = _rms(replay.run(rec.target, start, flat[..., 0], flat[..., 1]), rec.measured)
        errors = err.reshape(NUM_JOINTS, c, NUM_JOINTS)[joints, :, joints].T  # (C, 16)
        passes += 1
        new_best = errors.argmin(axis=0)
        if np.array_equal(new_best, best):
            break
        best = new_best
    if not np.isfinite(errors[best, np.arange(NUM_JOINTS)]).all():
        raise RuntimeError("every candidate diverged in simulation for some joint; check the grid and sim.timestep")
    return SysIdResult(cfg.grid, errors, best, passes)


def make_recording(stiffness, damping, protocol: StepProtocol | None = None, hand: HandConfig | None = None,
                   sim: SimConfig | None = None, noise_deg: float = 0.0, seed: int = 0) -> JointRecording:
    """A recording of the simulated hand with the given true gains (scalars or 16 values each).

    `noise_deg`: std (deg) of Gaussian noise added to the "measured" angles, as an encoder
    would; the start sample stays exact so the replay starts where the hand was.
    """
    protocol = protocol or StepProtocol()
    hand = hand or HandConfig()
    sim = sim or SimConfig(nthread=1)
    true_k = np.broadcast_to(np.asarray(stiffness, np.float64), (NUM_JOINTS,)).copy()
    true_d = np.broadcast_to(np.asarray(damping, np.float64), (NUM_JOINTS,)).copy()
    dataclasses.replace(hand, stiffness=tuple(true_k), damping=tuple(true_d))  # validates the values
    check(noise_deg >= 0, "noise_deg", f"must be >= 0, got {noise_deg}")
    target = protocol.targets(hand)
    replay = StepReplay(hand, sim, protocol.control_dt)
    measured = replay.run(target, target[0], true_k[None], true_d[None])[0]
    if not np.isfinite(measured).all():
        raise RuntimeError("the simulated hand diverged; lower sim.timestep or the true stiffness")
    if noise_deg > 0:
        rng = np.random.default_rng(seed)
        measured[1:] += np.deg2rad(noise_deg) * rng.standard_normal(measured[1:].shape)
    time = np.arange(len(target)) * protocol.control_dt
    return JointRecording(time, target, measured, true_k, true_d, source="<simulated>")


# --- output ----------------------------------------------------------------------------
def report(result: SysIdResult, rec: JointRecording) -> dict:
    """A plain dict (YAML) of the grid, per-joint best pair and full error tables."""
    joints = {}
    for j, name in enumerate(JOINT_NAMES):
        entry = {"stiffness": float(result.stiffness[j]), "damping": float(result.damping[j]),
                 "rms_error_deg": round(float(np.rad2deg(result.best_errors[j])), 5),
                 "errors_deg": np.round(np.rad2deg(result.table(j)), 5).tolist()}
        if rec.true_stiffness is not None and rec.true_damping is not None:
            entry["true_pair"] = [float(rec.true_stiffness[j]), float(rec.true_damping[j])]
        joints[name] = entry
    return {
        "recording": rec.source,
        "samples": rec.num_samples,
        "control_dt": round(rec.period, 6),
        "grid": {"stiffness": list(result.grid.stiffness), "damping": list(result.grid.damping)},
        "passes": result.passes,
        "errors_layout": "errors_deg[i][j]: RMS error (deg) with stiffness[i], damping[j], other joints at their best",
        "joints": joints,
    }


def write_outputs(result: SysIdResult, rec: JointRecording, out: str | Path, base_hand: HandConfig,
                  refined=None) -> tuple[Path, Path]:
    """Write the hand config (a Baoding config fragment) to `out` and the report beside it.

    `out` loads with ``tacgnn <command> --config out.yaml``; the report is
    ``<out stem>.report.yaml``. With `refined` (a `sysid_refine.RefineResult`: passed in, not
    imported, as that module builds on this one) the hand takes the refined gains and the report
    adds their intervals.
    """
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    hand = result.hand_config(base_hand) if refined is None else dataclasses.replace(
        base_hand, stiffness=tuple(float(f"{v:.4g}") for v in refined.stiffness),
        damping=tuple(float(f"{v:.4g}") for v in refined.damping))
    header = (f"# Hand identified by tacgnn sysid from {rec.source}.\n"
              "# Use with: tacgnn <command> --config this.yaml  (a Baoding config with only 'hand' set)\n")
    atomic_write_text(out, header + yaml.safe_dump({"hand": to_dict(hand)}, sort_keys=False,
                                                   default_flow_style=None, width=120))
    report_path = out.with_name(f"{out.stem}.report.yaml")
    content = report(result, rec)
    if refined is not None:
        content["refined"] = refined.report()
    atomic_write_text(report_path, yaml.safe_dump(content, sort_keys=False, default_flow_style=None, width=120))
    return out, report_path


def summary(result: SysIdResult, rec: JointRecording) -> str:
    """A table for the terminal: joint, best pair, its RMS error, and the truth when known."""
    k_true, d_true = rec.true_stiffness, rec.true_damping
    known = k_true is not None and d_true is not None
    lines = [f"{'joint':<10} {'stiffness':>9} {'damping':>8} {'rms err (deg)':>14}" + ("   true" if known else "")]
    for j, name in enumerate(JOINT_NAMES):
        line = (f"{name:<10} {result.stiffness[j]:>9.4g} {result.damping[j]:>8.4g} "
                f"{np.rad2deg(result.best_errors[j]):>14.4f}")
        if k_true is not None and d_true is not None:
            ok = result.stiffness[j] == k_true[j] and result.damping[j] == d_true[j]
            line += f"   ({k_true[j]:.4g}, {d_true[j]:.4g}) {'ok' if ok else 'MISMATCH'}"
        lines.append(line)
    return "\n".join(lines)
