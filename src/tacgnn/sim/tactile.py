"""The tactile skin model: taxel readings from simulated contacts, for a batch of envs.

MuJoCo resolves a contact between a ball and a link into one point with one force.
A real skin is compliant: the pressed area grows with the force and spreads it over
several taxels. We model each contact as a Hertzian pressure distribution

    p(r) ~ sqrt(1 - r^2 / a^2)   for r < a,    a = a_1N * F_n^(1/3),

centred on the contact point, where ``a_1N`` (`Patch.contact_radius`) is the
radius pressed by 1 N on that patch. Taxel i of the contact's patch reads

    f_i = F_n * w_i / max(sum_j w_j, 0.5 * E),   w_i = sqrt(max(0, 1 - d_i^2 / a^2)),

with d_i the taxel's distance to the contact point and E = 2 pi a^2 / (3 pitch^2) the
sum of w over an unbounded grid. Inside a patch the readings sum to F_n; a contact
half off the skin loses the part that falls off. Readings of several contacts add;
values below the threshold read 0; then multiplicative Gaussian noise.

The contacts come from one MuJoCo ``contact`` sensor per patch (the K strongest
contacts of the patch's link, computed in C by the engine), so the per-step cost in
Python is a handful of vectorised numpy calls for the whole batch.
"""

from __future__ import annotations

import mujoco
import numpy as np

from tacgnn.hand.skin_layout import SkinLayout

SLOT_SIZE = 7  # found, force (normal, tangent x2), pos (3)
_CONTACT_DATA = mujoco.mjtConDataField.mjCONDATA_FOUND, mujoco.mjtConDataField.mjCONDATA_FORCE, \
    mujoco.mjtConDataField.mjCONDATA_POS
_REDUCE_MAXFORCE = 2


def sensor_name(patch_name: str) -> str:
    return f"skin_{patch_name}"


def add_skin_sensors(spec: mujoco.MjSpec, layout: SkinLayout, contacts_per_patch: int) -> None:
    """Add one contact sensor per patch, reporting the patch link's strongest contacts."""
    body_names = {b.name for b in spec.bodies}
    bits = sum(1 << int(f) for f in _CONTACT_DATA)
    for patch in layout.patches:
        if patch.body not in body_names:
            raise ValueError(f"skin patch '{patch.name}' is on link '{patch.body}', "
                             f"which the model does not have (links: {sorted(body_names)})")
        sensor = spec.add_sensor(name=sensor_name(patch.name), type=mujoco.mjtSensor.mjSENS_CONTACT,
                                 objtype=mujoco.mjtObj.mjOBJ_BODY, objname=patch.body)
        sensor.intprm = [bits, _REDUCE_MAXFORCE, contacts_per_patch]


class TactileModel:
    """Turns link poses and contact sensor data of N envs into taxel readings and positions.

    Args:
        layout: the skin.
        model: a compiled model that has the skin's sensors (see `add_skin_sensors`).

    Shapes (N envs, T taxels, P patches, K contacts per patch):
        positions(xpos (N, nbody, 3), xmat (N, nbody, 9)) -> (N, T, 3) world, float32
        readings(sensordata (N, nsensordata), xpos, xmat, rng) -> (N, T) newtons, float32
    """

    def __init__(self, layout: SkinLayout, model: mujoco.MjModel):
        self.layout = layout
        self.num_taxels = layout.num_taxels
        patches = layout.patches
        self.body_ids = np.array([model.body(p.body).id for p in patches])
        sensors = [model.sensor(sensor_name(p.name)) for p in patches]
        self.contacts_per_patch = int(sensors[0].dim[0]) // SLOT_SIZE
        self.sensor_adr = np.array([s.adr[0] for s in sensors])
        if any(int(s.dim[0]) != self.contacts_per_patch * SLOT_SIZE for s in sensors):
            raise ValueError("all skin sensors must report the same number of contacts")

        local, normals = zip(*(p.local_positions() for p in patches))
        self.local_positions = np.concatenate(local).astype(np.float32)  # (T, 3) link frames
        self.local_normals = np.concatenate(normals).astype(np.float32)
        self.patch_of_taxel = layout.patch_index()
        self._radius = np.array([p.contact_radius for p in patches])
        self._inv_pitch2 = np.array([1.0 / p.pitch**2 for p in patches])
        # Patches of equal size are processed together (fewer numpy calls, no padding):
        # per group, the patch indices, their taxels' link-frame positions (G, T_g, 3),
        # and each taxel's index in the skin vector (G, T_g).
        offsets = layout.offsets()
        self._groups = []
        for size in sorted({p.size for p in patches}):
            members = np.array([i for i, p in enumerate(patches) if p.size == size])
            table = np.stack([np.concatenate(local)[offsets[i]:offsets[i + 1]] for i in members]).astype(np.float32)
            index = np.stack([np.arange(offsets[i], offsets[i + 1]) for i in members])
            self._groups.append((members, table, np.sum(table**2, axis=-1), index))
        # gather indices of all slots' (normal force, position) in the sensordata row
        slot = np.arange(self.contacts_per_patch) * SLOT_SIZE
        base = self.sensor_adr[:, None] + slot[None, :]  # (P, K)
        self._force_idx = base + 1
        self._pos_idx = base[..., None] + 4 + np.arange(3)

    def contacts(self, sensordata: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Normal forces (N, P, K) and world contact points (N, P, K, 3) from sensordata."""
        return sensordata[:, self._force_idx], sensordata[:, self._pos_idx]

    def positions(self, xpos: np.ndarray, xmat: np.ndarray) -> np.ndarray:
        """World positions (N, T, 3) of all taxels: x_link + R_link p_local."""
        n = xpos.shape[0]
        out = np.empty((n, self.num_taxels, 3), np.float32)
        offsets = self.layout.offsets()
        for p, body in enumerate(self.body_ids):
            # One small GEMM per patch for all envs: (n_p, 3) @ (3, N*3), R^T stacked by env.
            rot_t = xmat[:, body].reshape(n, 3, 3).transpose(2, 0, 1).reshape(3, 3 * n)
            local = self.local_positions[offsets[p]:offsets[p + 1]]
            world = (local @ rot_t.astype(np.float32)).reshape(-1, n, 3).transpose(1, 0, 2)
            out[:, offsets[p]:offsets[p + 1]] = world + xpos[:, None, body]
        return out

    def readings(self, sensordata: np.ndarray, xpos: np.ndarray, xmat: np.ndarray,
                 rng: np.random.Generator | None = None) -> np.ndarray:
        """Taxel readings (N, T): each contact's normal force spread over its patch."""
        n = sensordata.shape[0]
        force, point = self.contacts(sensordata)
        out = np.zeros(n * self.num_taxels, np.float32)
        for members, table, sq_norm, index in self._groups:
            env, member, slot = np.nonzero(force[:, members] > 0)
            if len(env) == 0:
                continue
            patch = members[member]
            body = self.body_ids[patch]
            f = force[env, patch, slot]
            rot = xmat[env, body].reshape(-1, 3, 3)
            # contact point in the link frame: R^T (c - x)
            local = np.einsum("mji,mj->mi", rot, point[env, patch, slot] - xpos[env, body]).astype(np.float32)
            # w = sqrt(max(0, 1 - d^2/a^2)), d^2 = |l|^2 - 2 l.c + |c|^2, computed in place
            a2 = ((self._radius[patch] * np.cbrt(f)) ** 2).astype(np.float32)
            w = (table[member] @ local[:, :, None])[..., 0]  # batched matmul: faster than einsum here
            w *= 2.0
            w -= sq_norm[member]
            w -= np.sum(local * local, axis=1)[:, None]
            w /= a2[:, None]
            w += 1.0
            np.maximum(w, 0.0, out=w)
            np.sqrt(w, out=w)
            expected = (2.0 * np.pi / 3.0) * a2 * self._inv_pitch2[patch]
            w *= (f / np.maximum(w.sum(axis=1), 0.5 * expected)).astype(np.float32)[:, None]
            np.add.at(out, (index[member] + (env * self.num_taxels)[:, None]).ravel(), w.ravel())
        out = out.reshape(n, self.num_taxels)
        out[out < self.layout.threshold] = 0.0
        if rng is not None and self.layout.noise > 0:
            active = out > 0
            out[active] *= 1.0 + self.layout.noise * rng.standard_normal(active.sum()).astype(np.float32)
            np.maximum(out, 0.0, out=out)
        return out
