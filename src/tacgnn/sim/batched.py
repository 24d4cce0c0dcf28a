"""N copies of one model stepped together on a thread pool, with arrays in and out.

A thin layer over `mujoco.batch.Batch` (MuJoCo >= 4.0), which keeps each
simulation's integration state in one row of a (N, nstate) array and steps the
rows on C threads with results bit-identical to stepping them one by one. We add
what an RL environment needs around it: named views, per-env model parameters for
domain randomisation, and detection of diverging envs (NaN, Inf or runaway speed),
which MuJoCo would otherwise reset silently.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import mujoco
import numpy as np
from mujoco import batch as mjbatch

log = logging.getLogger(__name__)


class SimulationDiverged(RuntimeError):
    """Raised by code that cannot recover from a diverged env (the envs reset them instead)."""


class BatchedSim:
    """A batch of `num_envs` simulations of `model`.

    Attributes (live arrays, one row per env):
        qpos (N, nq), qvel (N, nv), ctrl (N, nu), xfrc_applied (N, nbody, 6): state, writable.
        xpos (N, nbody, 3), xmat (N, nbody, 9), sensordata (N, nsensordata),
        actuator_force (N, nu): derived, read-only, as of the start of the last substep.
    """

    def __init__(self, model: mujoco.MjModel, num_envs: int, nthread: int = 2,
                 max_speed: float = 1000.0):
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.model = model
        self.num_envs = num_envs
        self.max_speed = max_speed
        self.batch = mjbatch.Batch(model, num_envs, nthread=nthread)
        b = self.batch
        self.time = b.bind("time")
        self.qpos = b.bind("qpos")
        self.qvel = b.bind("qvel")
        self.ctrl = b.bind("ctrl")
        self.xfrc_applied = b.bind("xfrc_applied")
        self.qacc_warmstart = b.bind("qacc_warmstart")
        self.xpos = b.bind("xpos")
        self.xmat = b.bind("xmat")
        self.sensordata = b.bind("sensordata")
        self.actuator_force = b.bind("actuator_force")
        b.reset([0], stage=mujoco.mjtStage.mjSTAGE_NONE)
        self._default_state = b.state[0].copy()  # the state row of a reset simulation

    def expand(self, field: str) -> np.ndarray:
        """Per-env (N, ...) values of model field `field` (e.g. 'body_mass', 'opt.gravity')."""
        return self.batch.expand(field)

    def set_const(self, ids: np.ndarray) -> None:
        """Recompute the constants MuJoCo derives at compile time (a free body's mass matrix,
        `dof_M0`, among them) for envs `ids` after their masses or inertias changed."""
        self.batch.set_const(ids)

    def reset(self, ids: np.ndarray) -> None:
        """Reset envs `ids` to the model defaults (write qpos etc. after, then `forward`).

        A reset sets a simulation's state row and nothing else, so unless a default
        (qpos0 etc.) was made per env, copying the saved row does it 10x faster than the
        engine's reset.
        """
        if self.batch.expanded("qpos0") is not None:
            self.batch.reset(ids, stage=mujoco.mjtStage.mjSTAGE_NONE)
        else:
            self.batch.state[ids] = self._default_state

    def forward(self, ids: np.ndarray | None = None) -> None:
        """Recompute derived quantities (poses, contacts, sensors) of envs `ids` at their state."""
        self.batch.forward(ids)

    def step(self, nstep: int) -> np.ndarray:
        """Advance every env by `nstep` physics steps; return a (N,) mask of diverged envs.

        A diverged env (MuJoCo error, non-finite state or a body faster than
        `max_speed`) is logged; its state is meaningless until the caller resets it.
        """
        failed = self._engine_call(lambda: self.batch.step(nstep=nstep))
        return self._diverged(failed, self.qpos, self.qvel)

    def step_controls(self, controls: np.ndarray) -> np.ndarray:
        """Advance every env by ``controls.shape[1]`` physics steps, holding ``controls[:, k]`` (N,
        nstep, nu) during step k; return the diverged mask of `step` checked after every physics step.

        Bit for bit the same as setting `ctrl` and calling ``step(1)`` per physics step, in one call
        to the thread pool (for controls that change between physics steps: action latency). A
        rollout stops a simulation at a warning that stepping goes on after (a bad control, a full
        contact buffer); then this control step is stepped again one physics step per call.
        """
        nstep, start, warned = controls.shape[1], self.batch.state.copy(), self.batch.warning.copy()
        try:
            records = self.batch.rollout(nstep, control=controls, record=("qpos", "qvel"))
            if np.array_equal(self.batch.warning, warned):
                return self._diverged(np.zeros(self.num_envs, bool), records["qpos"], records["qvel"])
        except mjbatch.SimulationError:
            pass  # stepped again below, which names the envs
        self.batch.state[...] = start
        return step_each(self, controls)

    def _engine_call(self, run: Callable[[], object]) -> np.ndarray:
        """Run the engine call `run`; the (N,) mask of envs MuJoCo raised in."""
        failed = np.zeros(self.num_envs, bool)
        try:
            run()
        except mjbatch.SimulationError as err:
            failed[err.ids] = True
            log.warning("MuJoCo error in envs %s: %s", err.ids.tolist(), err)
        return failed

    def _diverged(self, failed: np.ndarray, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        """`failed`, or non-finite `qpos` or a speed in `qvel` over `max_speed` ((N, ..., nq) and
        (N, ..., nv): any physics step of an env), logged."""
        n = self.num_envs
        # NaN fails every comparison: one test catches non-finite and runaway speeds
        bad = failed | ~(np.abs(qvel.reshape(n, -1)).max(1, initial=0.0) <= self.max_speed) \
            | ~np.isfinite(qpos.reshape(n, -1)).all(1)
        if bad.any():
            log.warning("simulation diverged in envs %s; they will be reset", np.flatnonzero(bad).tolist())
        return bad


def step_each(sim: Any, controls: np.ndarray) -> np.ndarray:
    """Step a sim (`BatchedSim`, `WarpSim`) one physics step per call with ``ctrl = controls[:, k]``
    (N, nstep, nu) during step k; the (N,) mask of envs that diverged in any of them."""
    diverged = np.zeros(sim.num_envs, bool)
    for k in range(controls.shape[1]):
        sim.ctrl[:] = controls[:, k]
        diverged |= sim.step(1)
    return diverged
