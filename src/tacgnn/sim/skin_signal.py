"""What a real resistive skin makes of the contact forces, and its calibration.

`tacgnn.sim.tactile` gives each taxel the normal force pressing it: an ideal skin that reads
exactly 0 where nothing presses. A real skin never does. Between the contact model and every
consumer (observation, perception, datasets) `SkinSignal` turns the ideal forces of each frame
into the raw values a real array reports, then passes them through the same calibration as the
real hand's path (`calibrated`: subtract the rest baseline, clip at 0, zero what is below the
taxel's threshold, multiply by the gain, zero dead taxels), so a policy sees in simulation what
it will see on the hand. Per frame, for each env and taxel i with ideal force f_i:

    c_i = f_i + crosstalk * mean_{j ~ i} f_j                 neighbours j within 1.5 pitches
    m_i <- m_i + (dt / relaxation_time) (c_i - m_i)          the skin's slow memory of its load
    y_i = min(g_i ((1 - relaxation) c_i + relaxation m_i), saturation)
    raw_i = quantise(y_i + offset_i + drift_i(t) + noise_floor * N(0, 1)),   drift_i(t) = d_i + v_i t

so a step load first reads (1 - relaxation) of itself and creeps up (creep), and a released
taxel keeps reading part of its past load for a while (hysteresis). The per-taxel gain g_i is a
patch gain times a taxel's own spread; the offset is the taxel's rest value; the drift a slow
ramp from where the calibration left it (over seconds, temperature drift is close to linear).
Dead taxels read 0; stuck taxels read a constant (above their baseline: a phantom press).

Each env is one skin, drawn at reset and calibrated there as the real path does it: rest
frames (nothing pressing) give the baseline (their mean) and the threshold (`calibration_sigmas`
times their std, at least `min_threshold`); a patch load gives the patch gain within
`patch_gain_error`. The drift then carries on from the calibration, which is
`calibration_age` seconds old. With `baseline_tracking` (the default) the baseline then follows
each taxel that reads no touch (`track_baseline`, the drivers' auto-zero): a skin drifting for
minutes keeps reading 0 at rest, where a fixed baseline would read the drift as touches.
Parameters and their reasons: `SkinSignalConfig`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from tacgnn.config import check
from tacgnn.hand.skin_layout import SkinLayout
from tacgnn.sim.tactile import LazyKernel

Range = tuple[float, float]


@dataclass(frozen=True)
class SkinSignalConfig:
    """The skin's signal chain. 'ideal': the contact model's forces as they are (the paper's
    simulated skin). 'real' (the default): a resistive array and its calibration, with the values
    below. Forces in N (one raw unit = 1 N before gain); times in s."""

    preset: Literal["ideal", "real"] = "real"
    noise_floor: float = 0.01
    """Std (N) of the white noise on every taxel, pressed or not: a few ADC steps, as resistive
    arrays read at rest."""
    offset: Range = (0.05, 0.3)
    """Rest value (N) of each taxel, uniform: the calibration's baseline removes it."""
    drift_rate: float = 0.001
    """Std (N/s) of each taxel's baseline drift speed v_i: resistive skins drift with temperature
    and load history."""
    calibration_age: Range = (0.0, 60.0)
    """Seconds between the calibration and the episode's start, uniform: the drift since then is
    a baseline error the calibration does not know."""
    gain_spread: float = 0.15
    """Log-normal std of each taxel's gain: taxels of one array differ by 10-20 %."""
    patch_gain_spread: float = 0.2
    """Log-normal std of each patch's gain (the calibration measures it)."""
    patch_gain_error: float = 0.05
    """Relative std of the calibration's patch gain: a reference load is not exact."""
    relaxation: float = 0.1
    """Share of a load the skin first misses and creeps to (and keeps after release)."""
    relaxation_time: float = 0.5
    """Time constant (s) of that creep and recovery."""
    crosstalk: float = 0.05
    """Share of the mean of a taxel's neighbours' load it reads too (shared rows and columns)."""
    saturation: float = 3.0
    """Largest load (N) one taxel reports: the ADC's full scale."""
    quantisation: float = 0.002
    """ADC step (N): 12 bits over the full scale and the offsets."""
    dead_fraction: Range = (0.0, 0.05)
    """Share of taxels that read 0 (a broken line), uniform per skin."""
    stuck_fraction: Range = (0.0, 0.01)
    """Share of taxels stuck at a constant since the calibration, uniform per skin."""
    stuck_level: Range = (0.05, 1.0)
    """How far (N) above its baseline a stuck taxel reads, uniform."""
    calibration_sigmas: float = 4.0
    """Threshold = this many rest stds (as `tacgnn calibrate-skin`)."""
    min_threshold: float = 0.05
    """... at least this (N): drift since the calibration must not read as a touch."""
    rest_frames: int = 16
    """Rest frames the calibration averages."""
    baseline_tracking: float = 5.0
    """Time constant (s) with which a taxel's baseline follows its raw value while it reads no touch
    (0: the calibration's baseline, fixed). A fixed baseline fails within minutes: at 1 mN/s of drift
    a simulated hand on ROS went from 91 % to 9 % success over 256 episodes (5 min) as drifted
    taxels crossed their thresholds; tracking keeps the baseline within drift x 5 s (~5 mN)."""

    def __post_init__(self) -> None:
        check(self.preset in ("ideal", "real"), "skin_signal.preset", f"must be 'ideal' or 'real', got {self.preset!r}")
        for name in ("noise_floor", "drift_rate", "gain_spread", "patch_gain_spread", "patch_gain_error",
                     "crosstalk", "quantisation", "min_threshold", "calibration_sigmas"):
            value = getattr(self, name)
            check(0 <= value <= 1e3, f"skin_signal.{name}", f"must be in [0, 1000], got {value}")
        for name in ("offset", "calibration_age", "dead_fraction", "stuck_fraction", "stuck_level"):
            lo, hi = getattr(self, name)
            check(0 <= lo <= hi <= 1e6, f"skin_signal.{name}", f"needs 0 <= low <= high, got ({lo}, {hi})")
        for name in ("dead_fraction", "stuck_fraction"):
            check(getattr(self, name)[1] <= 1, f"skin_signal.{name}", "is a share of the taxels: at most 1")
        check(0 <= self.relaxation < 1, "skin_signal.relaxation", f"must be in [0, 1), got {self.relaxation}")
        check(1e-3 <= self.relaxation_time <= 1e3, "skin_signal.relaxation_time",
              f"must be in [0.001, 1000] s, got {self.relaxation_time}")
        check(self.saturation > self.min_threshold, "skin_signal.saturation",
              f"must be above skin_signal.min_threshold ({self.min_threshold} N), or no touch is ever read; "
              f"got {self.saturation}")
        check(self.saturation <= 1e4, "skin_signal.saturation", f"must be <= 10000 N, got {self.saturation}")
        check(2 <= self.rest_frames <= 1000, "skin_signal.rest_frames", f"must be in 2..1000, got {self.rest_frames}")
        check(0 <= self.baseline_tracking <= 1e6, "skin_signal.baseline_tracking",
              f"must be in [0, 1e6] s (0: off), got {self.baseline_tracking}")

    def tracking_rate(self, frame_dt: float) -> float:
        """The share of the gap to the raw value a quiet taxel's baseline closes per frame (0: off)."""
        return min(frame_dt / self.baseline_tracking, 1.0) if self.baseline_tracking > 0 else 0.0

    @property
    def is_ideal(self) -> bool:
        return self.preset == "ideal"


def calibrated(raw: np.ndarray, baseline: np.ndarray, threshold: np.ndarray, gain: np.ndarray,
               dead: np.ndarray) -> np.ndarray:
    """Readings from raw values: max(raw - baseline, 0), 0 below the threshold, times the gain,
    0 on dead taxels. The one place of the calibration's maths: the real hand's `SkinProcessor`
    and the simulated skin both apply it.

    Shapes: raw (..., T); the others broadcast against it. Returns float32.
    """
    x = np.maximum(raw - baseline, 0.0)
    x[x < threshold] = 0.0
    x *= gain
    x = np.where(dead, 0.0, x)
    return x.astype(np.float32)


def track_baseline(raw: np.ndarray, baseline: np.ndarray, threshold: np.ndarray, rate: float) -> None:
    """Auto-zero, in place on `baseline`: where a taxel reads no touch (raw - baseline below its
    threshold) its baseline moves `rate` of the way to the raw value; pressed taxels keep theirs.
    The real hand's `SkinProcessor` and the simulated skin both apply it after `calibrated`.

    Shapes: raw (n, T) or (T,); baseline the same (float32); threshold broadcasts.
    """
    gap = raw - baseline
    baseline += np.where(gap < threshold, np.float32(rate) * gap, np.float32(0.0)).astype(baseline.dtype)


_BANK_SIZE = 1 << 22
_bank: np.ndarray | None = None


def noise_draws(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """Standard normal float32 values of `shape`: a window of a fixed bank of 4 M draws at an offset
    from `rng` (one draw per frame instead of one per taxel: 30x cheaper; a frame's noise is white,
    and two frames share values only where their random windows overlap). Larger frames draw afresh."""
    global _bank
    size = int(np.prod(shape))
    if size > _BANK_SIZE // 4:
        return rng.standard_normal(shape, dtype=np.float32)
    if _bank is None:
        _bank = np.random.default_rng(0x5EED).standard_normal(_BANK_SIZE, dtype=np.float32)
    start = int(rng.integers(0, _BANK_SIZE - size))
    return _bank[start:start + size].reshape(shape)


def neighbour_table(layout: SkinLayout, reach: float = 1.5) -> np.ndarray:
    """(T, K) indices of each taxel's neighbours in its patch (closer than `reach` pitches), padded
    with T (a column that reads 0)."""
    lists = []
    for patch, first in zip(layout.patches, layout.offsets()):
        x = patch.local_positions()[0]
        d = np.linalg.norm(x[:, None] - x[None], axis=-1)
        near = (d < reach * patch.pitch) & (d > 0)
        lists += [first + np.flatnonzero(row) for row in near]
    width = max(1, max(len(n) for n in lists))
    table = np.full((len(lists), width), len(lists), np.int64)
    for i, n in enumerate(lists):
        table[i, :len(n)] = n
    return table


def _chain_kernel(forces, rows, neighbours, count, memory, gain, offset, drift, drift_speed, baseline, threshold,
                  calibration_gain, dead, stuck, noise, advance, crosstalk, alpha, relaxation, saturation,
                  noise_floor, step, inverse_step, tracking, raw, out):  # pragma: no cover (compiled)
    """`SkinSignal.raw`, `calibrated` and `track_baseline` as one compiled pass over each env's taxels:
    the same model and float32 arithmetic, in the same order (crosstalk spread from the pressed
    taxels only)."""
    num_taxels = forces.shape[1]
    one = np.float32(1.0)
    leak = np.zeros(num_taxels + 1, np.float32)
    for r in range(forces.shape[0]):
        e = rows[r]
        leak[:] = 0.0
        for t in range(num_taxels):
            if forces[r, t] != 0 and crosstalk > 0:
                share = crosstalk * forces[r, t]
                for k in range(neighbours.shape[1]):
                    j = neighbours[t, k]
                    leak[j] += share / count[j]
        for t in range(num_taxels):
            load = forces[r, t] + leak[t]
            m = memory[e, t] + alpha * (load - memory[e, t])
            memory[e, t] = m
            y = min(gain[e, t] * ((one - relaxation) * load + relaxation * m), saturation)
            d = drift[e, t]
            if advance:
                d += drift_speed[e, t]
                drift[e, t] = d
                y += noise_floor * noise[r, t]
            v = max(y + offset[e, t] + d, np.float32(0.0))
            if step > 0:
                v = np.float32(np.rint(v * inverse_step)) * step
            if stuck[e, t] > 0:
                v = stuck[e, t]
            if dead[e, t]:
                v = np.float32(0.0)
            raw[r, t] = v
            gap = v - baseline[e, t]
            x = max(gap, np.float32(0.0))
            out[r, t] = np.float32(0.0) if x < threshold[e, t] or dead[e, t] else x * calibration_gain[e, t]
            if tracking > 0 and gap < threshold[e, t]:
                baseline[e, t] += tracking * gap


_chain = LazyKernel(_chain_kernel)


def _rest_kernel(z, offset, dead, noise_floor, step, inverse_step, mean, std, all_zero):  # pragma: no cover (compiled)
    """The calibration's rest frames (n, F, T) from their normal draws `z`, in place, and per taxel
    their mean, std and whether all read 0: `SkinSignal.reset`'s numpy path (quantise, `mean(1)`,
    `std(1)`) in the same float64 operations and order, without its (n, F, T) temporaries."""
    n, frames, num_taxels = z.shape
    for k in range(n):
        for f in range(frames):
            for t in range(num_taxels):
                v = max(z[k, f, t] * noise_floor + offset[k, t], 0.0)
                if step > 0:
                    v = np.rint(v * inverse_step) * step
                z[k, f, t] = 0.0 if dead[k, t] else v
        for t in range(num_taxels):
            total = z[k, 0, t]
            zero = total == 0
            for f in range(1, frames):
                total += z[k, f, t]
                zero = zero and z[k, f, t] == 0
            m = total / frames
            d = z[k, 0, t] - m
            spread = d * d
            for f in range(1, frames):
                d = z[k, f, t] - m
                spread += d * d
            mean[k, t], std[k, t], all_zero[k, t] = m, np.sqrt(spread / frames), zero


_rest = LazyKernel(_rest_kernel)


def _draw_kernel(g, arrays, normal):  # pragma: no cover (compiled)
    """Fill each 1-D array of `arrays` in turn from the stream `g`: standard normals where `normal`, else
    uniforms in [0, 1). numba's Generator draws numpy's streams (the same algorithms), 3x faster and
    without the GIL."""
    for j in range(len(arrays)):
        a = arrays[j]
        if normal[j]:
            for i in range(a.size):
                a[i] = g.standard_normal()
        else:
            for i in range(a.size):
                a[i] = g.random()


_draw = LazyKernel(_draw_kernel)


class SkinSignal:
    """One real skin per env: draws it at reset, calibrates it, and turns each frame's ideal forces
    into calibrated readings (see the module docstring). With the 'ideal' preset it passes the
    forces through unchanged and draws nothing.

    Args:
        config: the signal chain's parameters.
        layout: the skin (patches, pitches).
        num_envs: N.
        frame_dt: seconds between frames (the control step).

    Shapes (N envs, T taxels): ``__call__(forces (n, T), ids, rng) -> (n, T)`` float32.
    """

    use_compiled: bool = True  # False: the numpy paths (references of the compiled chain and calibration)
    STATE = ("memory", "drift", "drift_speed", "gain", "offset", "baseline", "threshold", "calibration_gain", "dead",
             "stuck")  # stuck: the raw value a stuck taxel reads (0: not stuck)

    def __init__(self, config: SkinSignalConfig, layout: SkinLayout, num_envs: int, frame_dt: float):
        self.config, self.frame_dt = config, frame_dt
        t = layout.num_taxels
        self.patch_of_taxel = layout.patch_index()
        self.num_patches = len(layout.patches)
        self.neighbours = neighbour_table(layout)
        counts = np.maximum((self.neighbours < t).sum(1), 1).astype(np.float32)
        self._neighbour_count_padded = np.append(counts, np.float32(1.0))  # the pad column's: any nonzero
        shape = (num_envs, t)
        self.memory = np.zeros(shape, np.float32)
        self.drift = np.zeros(shape, np.float32)
        self.drift_speed = np.zeros(shape, np.float32)  # N per frame
        self.gain = np.ones(shape, np.float32)
        self.offset = np.zeros(shape, np.float32)
        self.baseline = np.zeros(shape, np.float32)
        self.threshold = np.zeros(shape, np.float32)
        self.calibration_gain = np.ones(shape, np.float32)
        self.dead = np.zeros(shape, bool)
        self.stuck = np.zeros(shape, np.float32)  # the raw value it reads; 0: not stuck
        self.tracking = config.tracking_rate(frame_dt)

    def reset(self, ids: np.ndarray, rngs: list[np.random.Generator]) -> None:
        """Draw a new skin for each env in `ids` (from its own stream, `rngs[k]` for `ids[k]`) and
        calibrate it on rest frames.

        Each env's stream gives its draws in the order of the model below (into rows of batch
        arrays); the maths then runs on all the reset envs at once, element for element as per env.
        """
        c = self.config
        if c.is_ideal:
            return
        n, t, p = len(ids), self.memory.shape[1], self.num_patches
        patch_z, measure_z = np.empty((n, p)), np.empty((n, p))
        gain_z, offset_u, dead_u, stuck_u, speed_z, level_u = np.empty((6, n, t))
        rest_z = np.empty((n, c.rest_frames, t))
        dead_share, stuck_share, age = np.empty((3, n))
        draw = _draw.get() if self.use_compiled else None
        if draw is not None:  # the loop's draws below, in its order; a uniform(lo, hi) as lo + (hi - lo) u
            normal = np.array([1, 1, 0, 0, 0, 0, 0, 1, 1, 1, 0, 0], bool)
            shares = np.empty((3, n, 1))
            for k, g in enumerate(rngs):
                draw(g, (patch_z[k], gain_z[k], offset_u[k], dead_u[k], shares[0, k], stuck_u[k], shares[1, k],
                         rest_z[k].reshape(-1), measure_z[k], speed_z[k], shares[2, k], level_u[k]), normal)
            for out, u, (lo, hi) in zip((dead_share, stuck_share, age), shares,
                                        (c.dead_fraction, c.stuck_fraction, c.calibration_age)):
                out[:] = lo + (hi - lo) * u[:, 0]
        else:
            for k, g in enumerate(rngs):
                g.standard_normal(out=patch_z[k])
                g.standard_normal(out=gain_z[k])
                g.random(out=offset_u[k])  # g.uniform(lo, hi) is lo + (hi - lo) * g.random()
                g.random(out=dead_u[k])
                dead_share[k] = g.uniform(*c.dead_fraction)
                g.random(out=stuck_u[k])
                stuck_share[k] = g.uniform(*c.stuck_fraction)
                g.standard_normal(out=rest_z[k])
                g.standard_normal(out=measure_z[k])
                g.standard_normal(out=speed_z[k])
                age[k] = g.uniform(*c.calibration_age)
                g.random(out=level_u[k])
        patch_gain = np.exp(c.patch_gain_spread * patch_z)
        self.gain[ids] = patch_gain[:, self.patch_of_taxel] * np.exp(c.gain_spread * gain_z)
        offset = (c.offset[0] + (c.offset[1] - c.offset[0]) * offset_u).astype(np.float32)
        self.offset[ids] = offset
        dead = dead_u < dead_share[:, None]
        stuck = ~dead & (stuck_u < stuck_share[:, None])
        # the calibration: rest frames give the baseline and the threshold; a patch load the gain
        kernel = _rest.get() if self.use_compiled else None
        if kernel is None:
            rest_z *= c.noise_floor
            rest_z += offset[:, None]
            rest = self._quantise(rest_z)
            np.copyto(rest, 0.0, where=dead[:, None])
            rest_mean, rest_std, rest_zero = rest.mean(1), rest.std(1), (rest == 0).all(1)
        else:
            rest_mean, rest_std, rest_zero = np.empty((n, t)), np.empty((n, t)), np.empty((n, t), bool)
            kernel(rest_z, offset, dead, c.noise_floor, c.quantisation, 1.0 / c.quantisation if c.quantisation > 0
                   else 1.0, rest_mean, rest_std, rest_zero)
        baseline = rest_mean.astype(np.float32)
        threshold = np.maximum(c.calibration_sigmas * rest_std, c.min_threshold)
        self.dead[ids] = rest_zero
        measured = patch_gain * (1.0 + c.patch_gain_error * measure_z)
        self.calibration_gain[ids] = 1.0 / np.maximum(measured, 1e-3)[:, self.patch_of_taxel]
        # since then: drift (which a tracking baseline has followed, a time constant behind), and
        # the stuck taxels' phantom presses
        speed = c.drift_rate * speed_z
        drift = (speed * age[:, None]).astype(np.float32)
        self.drift[ids] = drift
        self.drift_speed[ids] = speed * self.frame_dt
        level = c.stuck_level[0] + (c.stuck_level[1] - c.stuck_level[0]) * level_u
        self.stuck[ids] = np.where(stuck, baseline + level, 0.0)
        if self.tracking > 0:  # an EMA behind a ramp: v tau (1 - exp(-age / tau))
            tau = c.baseline_tracking
            behind = speed * tau * -np.expm1(-age / tau)[:, None]
            baseline += np.where(dead | stuck, 0.0, drift - behind).astype(np.float32)
        self.baseline[ids] = baseline
        self.threshold[ids] = threshold
        self.memory[ids] = 0.0

    def __call__(self, forces: np.ndarray, ids: np.ndarray | slice, rng: np.random.Generator | None) -> np.ndarray:
        """Calibrated readings (n, T) of envs `ids` from their ideal forces (n, T), advancing each
        env's skin by one frame; per-frame noise from `rng` (None: no noise, no drift step)."""
        if self.config.is_ideal:
            return forces
        kernel = _chain.get() if self.use_compiled else None
        if kernel is None:
            raw = self.raw(forces, ids, rng)
            baseline = self.baseline[ids]
            out = calibrated(raw, baseline, self.threshold[ids], self.calibration_gain[ids], self.dead[ids])
            if self.tracking > 0:
                track_baseline(raw, baseline, self.threshold[ids], self.tracking)
                self.baseline[ids] = baseline
            return out
        c = self.config
        f = np.ascontiguousarray(forces, np.float32)
        rows = np.arange(len(self.memory))[ids].astype(np.int64)
        noise = noise_draws(rng, f.shape) if rng is not None else np.zeros((1, 1), np.float32)
        raw, out = np.empty_like(f), np.empty_like(f)
        kernel(f, rows, self.neighbours, self._neighbour_count_padded, self.memory, self.gain, self.offset, self.drift,
               self.drift_speed, self.baseline, self.threshold, self.calibration_gain, self.dead, self.stuck, noise,
               rng is not None, np.float32(c.crosstalk), np.float32(self.frame_dt / c.relaxation_time),
               np.float32(c.relaxation), np.float32(c.saturation), np.float32(c.noise_floor),
               np.float32(c.quantisation), np.float32(1.0 / c.quantisation if c.quantisation > 0 else 1.0),
               np.float32(self.tracking), raw, out)
        self.last_raw = raw
        return out

    def raw(self, forces: np.ndarray, ids: np.ndarray | slice, rng: np.random.Generator | None) -> np.ndarray:
        """The raw values (n, T) the array reports for envs `ids` (what a driver publishes, before any
        calibration), advancing each env's skin by one frame; also kept as `last_raw`.

        The work is a few passes over the (n, T) frame, in place; crosstalk visits the pressed
        taxels only (a few % of them).
        """
        c = self.config
        load = np.array(forces, np.float32)  # a copy: the crosstalk adds to it
        rows, cols = np.nonzero(load)
        if len(rows) and c.crosstalk > 0:
            near = self.neighbours[cols]  # (m, K), padded with T
            share = (c.crosstalk * load[rows, cols])[:, None] / self._neighbour_count_padded[near]
            padded = np.zeros((len(load), load.shape[1] + 1), np.float32)
            np.add.at(padded, (np.repeat(rows, near.shape[1]), near.ravel()), share.ravel())
            load += padded[:, :-1]
        memory = self.memory[ids]
        memory += (self.frame_dt / c.relaxation_time) * (load - memory)
        self.memory[ids] = memory
        signal = load
        signal *= 1.0 - c.relaxation
        signal += c.relaxation * memory
        signal *= self.gain[ids]
        np.minimum(signal, c.saturation, out=signal)
        drift = self.drift[ids]
        if rng is not None:
            drift += self.drift_speed[ids]
            self.drift[ids] = drift
            signal += c.noise_floor * noise_draws(rng, signal.shape)
        signal += self.offset[ids]
        signal += drift
        raw = self._quantise(signal)
        stuck = self.stuck[ids]
        if stuck.any():
            raw = np.where(stuck > 0, stuck, raw)
        raw[self.dead[ids]] = 0.0
        self.last_raw = raw
        return raw

    def _quantise(self, raw: np.ndarray) -> np.ndarray:
        """The ADC's reading of `raw` (in place where it is float32): clipped at 0, to whole steps."""
        q = self.config.quantisation
        raw = np.maximum(raw, 0.0, out=raw if raw.dtype == np.float32 else None)
        if q > 0:
            raw *= 1.0 / q
            np.rint(raw, out=raw)
            raw *= q
        return raw

    def state_dict(self) -> dict[str, Any]:
        return {name: getattr(self, name).copy() for name in self.STATE}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        for name in self.STATE:
            getattr(self, name)[...] = state[name]
