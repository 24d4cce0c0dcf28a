"""System identification beyond the grid: per-joint least squares with MuJoCo's `mujoco.sysid`.

The grid search (`tacgnn.real.sysid.identify`) can only return values it tried. Starting
from its best pairs, this fits all 32 gains (stiffness and damping of each joint) to
the recording by nonlinear least squares: residuals are simulated minus measured joint
angles over the whole recording, every simulation of a batch (the finite-difference
Jacobian's 33 points) runs as one `BatchedSim`, and the optimizer is MuJoCo's own
(`mujoco.sysid.optimize`, backend ``mujoco.minimize.least_squares``).

Confidence intervals come from the Jacobian at the optimum (`mujoco.sysid.calculate_intervals`:
linearised, noise variance estimated from the residuals). They are computed per finger,
its four joints' residuals against its eight gains (the fingers move independently, and
each finger's noise is estimated from its own residuals). A joint's interval is
simultaneous for its two gains: each gain's interval is at level 1 - alpha / 2
(Bonferroni), so the truth lies inside both with probability >= 1 - alpha under the
model. Wide intervals say the recording does not pin a gain down (with 0.5 N m torque
limits, large steps saturate the motors and say little about stiffness).

Needs the ``sysid`` extra (``pip install 'tacgnn[sysid]'``, i.e. ``mujoco[sysid]``).
"""

from __future__ import annotations

import io
from dataclasses import dataclass

import numpy as np

from tacgnn.config import check
from tacgnn.hand.allegro import JOINT_NAMES, NUM_JOINTS
from tacgnn.real.joint_recording import JointRecording
from tacgnn.real.sysid import JOINTS_PER_FINGER, StepReplay, SysIdConfig

DIVERGED_RESIDUAL = 10.0
"""Residual (rad) given to samples of a diverged simulation: large, finite, so the optimizer backs off."""


@dataclass(frozen=True)
class RefineConfig:
    max_iters: int = 40
    stiffness_bounds: tuple[float, float] = (0.05, 50.0)
    damping_bounds: tuple[float, float] = (0.0, 5.0)
    alpha: float = 0.05
    """1 - confidence of each joint's (stiffness, damping) interval pair."""
    fd_step: float = 1e-6
    """Relative finite-difference step of the Jacobian."""

    def __post_init__(self) -> None:
        check(self.max_iters >= 1, "refine.max_iters", "must be >= 1")
        check(0 < self.stiffness_bounds[0] < self.stiffness_bounds[1], "refine.stiffness_bounds",
              "needs 0 < low < high")
        check(0 <= self.damping_bounds[0] < self.damping_bounds[1], "refine.damping_bounds", "needs 0 <= low < high")
        check(0 < self.alpha < 1, "refine.alpha", f"must be in (0, 1), got {self.alpha}")
        check(self.fd_step > 0, "refine.fd_step", "must be positive")


@dataclass(frozen=True, eq=False)
class RefineResult:
    stiffness: np.ndarray
    """(16,) fitted stiffness (N m/rad)."""
    damping: np.ndarray
    """(16,) fitted damping (N m s/rad)."""
    stiffness_half_width: np.ndarray
    """(16,) half width of each stiffness interval (inf: not identifiable from this recording)."""
    damping_half_width: np.ndarray
    rms: np.ndarray
    """(16,) RMS error (rad) of each joint at the fit."""
    alpha: float

    @property
    def stiffness_interval(self) -> np.ndarray:
        """(16, 2) low, high."""
        return np.stack([self.stiffness - self.stiffness_half_width, self.stiffness + self.stiffness_half_width], 1)

    @property
    def damping_interval(self) -> np.ndarray:
        return np.stack([self.damping - self.damping_half_width, self.damping + self.damping_half_width], 1)

    def covers(self, stiffness: np.ndarray, damping: np.ndarray) -> np.ndarray:
        """(16,) whether each joint's (stiffness, damping) lies inside both its intervals."""
        k, d = self.stiffness_interval, self.damping_interval
        return (k[:, 0] <= stiffness) & (stiffness <= k[:, 1]) & (d[:, 0] <= damping) & (damping <= d[:, 1])

    def report(self) -> dict:
        """Per joint: fit and interval, for the report YAML (`sysid.write_outputs` adds it)."""
        return {"method": "least squares (mujoco.sysid, MuJoCo's minimize) from the grid's best",
                "confidence": f"{100 * (1 - self.alpha):.0f} % simultaneous per joint (Bonferroni over its two gains)",
                "joints": {name: {"stiffness": float(self.stiffness[j]),
                                  "stiffness_interval": [float(v) for v in self.stiffness_interval[j]],
                                  "damping": float(self.damping[j]),
                                  "damping_interval": [float(v) for v in self.damping_interval[j]],
                                  "rms_error_deg": round(float(np.rad2deg(self.rms[j])), 5)}
                           for j, name in enumerate(JOINT_NAMES)}}


def _sysid():
    try:
        import mujoco.sysid as sysid

        sysid.optimize  # noqa: B018  (absent when the extra's dependencies are missing)
    except (ImportError, AttributeError) as err:
        raise ImportError("refining needs MuJoCo's system identification toolbox: "
                          "pip install 'tacgnn[sysid]' (mujoco[sysid])") from err
    return sysid


def refine(rec: JointRecording, start_stiffness: np.ndarray, start_damping: np.ndarray,
           cfg: SysIdConfig | None = None, refine_cfg: RefineConfig | None = None) -> RefineResult:
    """Least-squares gains for every joint of `rec`, from the start values (e.g. the grid's best)."""
    sysid = _sysid()
    cfg = cfg or SysIdConfig()
    rc = refine_cfg or RefineConfig()
    replay = StepReplay(cfg.hand, cfg.sim, rec.period)
    start = rec.measured[0]
    measured = rec.measured[1:]  # (T-1, 16); sample 0 is where every replay starts

    def residual_columns(x: np.ndarray) -> np.ndarray:
        """x (32, B): gains, stiffness then damping, per column -> (16 * (T-1), B) residuals, joint-major."""
        x = np.asarray(x, np.float64).reshape(2 * NUM_JOINTS, -1)
        sims = replay.run(rec.target, start, x[:NUM_JOINTS].T, x[NUM_JOINTS:].T)[:, 1:]  # (B, T-1, 16)
        r = np.where(np.isfinite(sims), sims - measured, DIVERGED_RESIDUAL)
        return r.transpose(2, 1, 0).reshape(-1, x.shape[1])

    lo = np.r_[np.full(NUM_JOINTS, rc.stiffness_bounds[0]), np.full(NUM_JOINTS, rc.damping_bounds[0])]
    hi = np.r_[np.full(NUM_JOINTS, rc.stiffness_bounds[1]), np.full(NUM_JOINTS, rc.damping_bounds[1])]
    x0 = np.clip(np.r_[np.asarray(start_stiffness, np.float64), np.asarray(start_damping, np.float64)], lo, hi)
    params = sysid.ParameterDict({"gains": sysid.Parameter("gains", x0, lo, hi)})
    params.move_off_bounds()

    def residual_fn(x, _params):
        return [residual_columns(x)], None, None

    opt, _ = sysid.optimize(params, residual_fn, optimizer="mujoco", verbose=False, max_iters=rc.max_iters,
                            eps=rc.fd_step, x_scale="jac", output=io.StringIO())  # no per-iteration printout
    x = opt["gains"].as_vector()

    # Jacobian at the optimum (central differences, one batch), intervals per finger
    r0 = residual_columns(x[:, None])[:, 0]
    step = rc.fd_step * np.maximum(1.0, np.abs(x)) * 100.0
    plus, minus = np.clip(x[:, None] + np.diag(step), lo[:, None], hi[:, None]), \
        np.clip(x[:, None] - np.diag(step), lo[:, None], hi[:, None])
    rr = residual_columns(np.concatenate([plus, minus], axis=1))
    jac = (rr[:, :x.size] - rr[:, x.size:]) / (plus - minus).diagonal()[None]
    samples = len(measured)
    half = np.full(2 * NUM_JOINTS, np.inf)
    for f in range(NUM_JOINTS // JOINTS_PER_FINGER):
        joints = np.arange(f * JOINTS_PER_FINGER, (f + 1) * JOINTS_PER_FINGER)
        rows = (joints[:, None] * samples + np.arange(samples)).ravel()
        cols = np.r_[joints, NUM_JOINTS + joints]
        _, h = sysid.calculate_intervals([r0[rows]], jac[np.ix_(rows, cols)], alpha=rc.alpha / 2)
        half[cols] = h
    rms = np.sqrt(np.mean(r0.reshape(NUM_JOINTS, samples) ** 2, axis=1))
    return RefineResult(x[:NUM_JOINTS], x[NUM_JOINTS:], half[:NUM_JOINTS], half[NUM_JOINTS:], rms, rc.alpha)


def refine_summary(result: RefineResult, rec: JointRecording) -> str:
    """A table for the terminal: per joint the fit, its simultaneous interval and the truth when known."""
    k_true, d_true = rec.true_stiffness, rec.true_damping
    inside = result.covers(k_true, d_true) if k_true is not None and d_true is not None else None
    known = inside is not None
    level = f"{100 * (1 - result.alpha):.0f} %"
    lines = [f"{'joint':<10} {'stiffness':>9} {f'[{level} interval]':>20} {'damping':>8} {f'[{level} interval]':>20} "
             f"{'rms (deg)':>9}" + ("   true" if known else "")]
    for j, name in enumerate(JOINT_NAMES):
        (k0, k1), (d0, d1) = result.stiffness_interval[j], result.damping_interval[j]
        line = (f"{name:<10} {result.stiffness[j]:>9.4g} {f'[{k0:.4g}, {k1:.4g}]':>20} {result.damping[j]:>8.4g} "
                f"{f'[{d0:.4g}, {d1:.4g}]':>20} {np.rad2deg(result.rms[j]):>9.4f}")
        if k_true is not None and d_true is not None and inside is not None:
            line += (f"   ({k_true[j]:.4g}, {d_true[j]:.4g}) "
                     f"{'inside' if inside[j] else 'OUTSIDE'}")
        lines.append(line)
    if inside is not None:
        lines.append(f"truth inside the {level} intervals for {int(inside.sum())} of {NUM_JOINTS} joints")
    return "\n".join(lines)
