"""The tactile skin model: taxel readings from simulated contacts, for a batch of envs.

MuJoCo resolves a contact between a ball and a link into one point with one force.
A real skin is compliant: the pressed area grows with the force and spreads it over
several taxels. We model each contact as a Hertzian pressure distribution

    p(r) ~ sqrt(1 - r^2 / a^2)   for r < a,    a = a_1N * F_n^(1/3),

centred on the contact point, where ``a_1N`` (`Patch.contact_radius`) is the
radius pressed by 1 N on that patch. Taxel i of the contact's patch reads

    f_i = F_n * w_i / max(sum_j w_j, k * E),   w_i = sqrt(max(0, 1 - d_i^2 / a^2)),

with d_i the taxel's distance to the contact point and E = 2 pi a^2 / (3 pitch^2) the
sum of w over an unbounded grid. Inside a patch, and on the border's strip half a pitch
wide that the outer taxels cover, the readings sum to F_n (k = `EDGE_FLOOR` is small
enough for that, corners included); a contact further off the skin loses what falls off.
Readings of several contacts add; values below the threshold read 0; then multiplicative
Gaussian noise.

The contacts come from one MuJoCo ``contact`` sensor per patch (the K strongest
contacts of the patch's link, computed in C by the engine). In Python, the cost per
step is a fixed number of vectorised numpy calls for the whole batch, and the work
per contact is proportional to the taxels its disc can reach, not to its patch's size:
a lookup grid around each patch (`_CandidateGrid`) lists, for any contact, the few
taxels that can lie within its radius.
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from tacgnn.hand.skin_layout import SkinLayout

SLOT_SIZE = 7  # found, force (normal, tangent x2), pos (3)
# Least share of the unbounded grid's weight sum E that normalises a contact's readings
# (see the module docstring): tests/test_tactile.py measures that covered contacts keep
# their force with it.
EDGE_FLOOR = 0.1
_CONTACT_DATA = mujoco.mjtConDataField.mjCONDATA_FOUND, mujoco.mjtConDataField.mjCONDATA_FORCE, \
    mujoco.mjtConDataField.mjCONDATA_POS
_REDUCE_MAXFORCE = 2

# Skin noise is counter-based: the draw for flat taxel index i (env * T + taxel) in a step
# is a pure function of (step seed, i), a splitmix64 hash of the two looked up in a table
# of 2^16 standard normal quantiles. A taxel's noise then does not depend on which other
# taxels are pressed or in what order the compiled kernel visits them, so the kernel and
# the numpy path agree draw for draw and the kernel applies the noise where it presses.
# One seed per step comes from the env's generator: seeded runs reproduce. Std 0.99999,
# tails cut at 4.3 sigma.
_NORMAL_BITS = 16
_normal_table: np.ndarray | None = None
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1, _MIX2 = np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB)
_TABLE_SHIFT = np.uint64(64 - _NORMAL_BITS)  # the hash's top bits index the table


def normal_table() -> np.ndarray:
    """Standard normal values at the centres of 2^16 equal-probability bins (float32)."""
    global _normal_table
    if _normal_table is None:
        from statistics import NormalDist
        quantiles = (np.arange(1 << _NORMAL_BITS) + 0.5) / (1 << _NORMAL_BITS)
        _normal_table = np.array([NormalDist().inv_cdf(q) for q in quantiles], np.float32)
    return _normal_table


def draw_step_seed(rng: np.random.Generator) -> np.uint64:
    """The step's noise seed, from the env's generator."""
    return np.uint64(rng.bit_generator.random_raw())  # 64 random bits, 40x faster than integers()


def counter_normal(seed: np.uint64, index: np.ndarray) -> np.ndarray:
    """Standard normal float32 draws for flat taxel indices `index` in the step of `seed`."""
    with np.errstate(over="ignore"):
        z = np.asarray(index).astype(np.uint64) * _GOLDEN + np.uint64(seed)
        z = (z ^ (z >> np.uint64(30))) * _MIX1
        z = (z ^ (z >> np.uint64(27))) * _MIX2
        z ^= z >> np.uint64(31)
    return normal_table()[(z >> _TABLE_SHIFT).astype(np.intp)]


def sensor_name(patch_name: str) -> str:
    return f"skin_{patch_name}"


def skin_sensor_columns(model: mujoco.MjModel) -> np.ndarray:
    """The sensordata columns the skin's contact sensors fill (those named by `sensor_name`)."""
    columns = [np.arange(s.adr[0], s.adr[0] + s.dim[0]) for s in map(model.sensor, range(model.nsensor))
               if s.name.startswith(sensor_name(""))]
    return np.concatenate(columns) if columns else np.zeros(0, dtype=np.int64)


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


# The candidate grid: cells one pitch wide, reaching two pitches beyond the taxels so that
# contacts a little off the skin still have a cell centre nearby; radii in quarter pitches.
_CELL_PITCHES = 1.0
_MARGIN_PITCHES = 2.0
_BIN_PITCHES = 0.25
# Envs per GEMM in `TactileModel.positions`: OpenBLAS runs GEMMs this small on one thread;
# on larger ones it starts threads, which made positions 30x slower with the cores busy.
_GEMM_ROWS = 64


class _CandidateGrid:
    """The taxels a contact can press, looked up from where it is in its link's frame.

    Around each patch lies a grid of cells in the link frame. Each cell lists the patch's
    taxels by distance from its centre, and counts those closer than each multiple of a
    bin width. A contact at distance s from its cell's centre can only press taxels within
    a + s of that centre (triangle inequality), so the first count(a + s) taxels of the
    list hold all it presses: exact for any force, and for any contact point (one outside
    the grid takes the nearest cell, with a larger s). The lists take cells x taxels per
    patch: 1.3 MB for the default skin.
    """

    def __init__(self, layout: SkinLayout):
        local = [p.local_positions()[0] for p in layout.patches]
        origin, cell_size, stride, last, first_cell = [], [], [], [], []
        order, counts, list_start = [], [], []
        num_cells = num_listed = 0
        for patch, x, first_taxel in zip(layout.patches, local, layout.offsets()):
            size, margin, bin_size = (k * patch.pitch for k in (_CELL_PITCHES, _MARGIN_PITCHES, _BIN_PITCHES))
            lo = x.min(0) - margin
            dims = np.ceil((x.max(0) + margin - lo) / size).astype(int) + 1
            cells = np.stack(np.meshgrid(*map(np.arange, dims), indexing="ij"), -1).reshape(-1, 3)
            dist = np.linalg.norm((lo + size * cells)[:, None] - x, axis=-1)  # (cells, taxels)
            order.append(first_taxel + np.argsort(dist, axis=1, kind="stable").ravel())
            # counts[c, k]: taxels closer than k bins to cell c's centre
            first_bin = (dist / bin_size).astype(int) + 1  # the first k that counts the taxel
            num_bins = first_bin.max() + 1
            per_bin = np.bincount((num_bins * np.arange(len(cells))[:, None] + first_bin).ravel(),
                                  minlength=len(cells) * num_bins)
            counts.append(per_bin.reshape(len(cells), num_bins).cumsum(axis=1))
            list_start.append(num_listed + patch.size * np.arange(len(cells)))
            origin.append(lo)
            cell_size.append(size)
            stride.append([dims[1] * dims[2], dims[2], 1])
            last.append(dims - 1)
            first_cell.append(num_cells)
            num_cells += len(cells)
            num_listed += len(cells) * patch.size
        small = np.min_scalar_type(layout.num_taxels)
        self.order = np.concatenate(order).astype(small)  # taxel indices in the skin vector
        # (cells * bins,); past a patch's last bin the count stays at the patch size
        self.num_bins = max(c.shape[1] for c in counts)
        padded = [np.pad(c, ((0, 0), (0, self.num_bins - c.shape[1])), mode="edge") for c in counts]
        self.counts = np.concatenate(padded).astype(small).ravel()
        self.list_start = np.concatenate(list_start)
        self.origin, self.cell_size = np.array(origin), np.array(cell_size)
        self.first_cell = np.array(first_cell)
        self.stride, self.last = np.array(stride, float), np.array(last, float)  # used with float cells

    def lookup(self, patch: np.ndarray, local: np.ndarray,
               radius: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where each contact's candidates start in `order`, and how many there are.

        Args: the contacts' patch indices (M,), points in the link frame (M, 3), radii (M,).
        """
        size = self.cell_size[patch]
        x = (local - np.take(self.origin, patch, axis=0)) / size[:, None]  # in cells
        q = np.clip(np.rint(x), 0, np.take(self.last, patch, axis=0))  # the nearest cell of the grid
        x -= q
        cell = np.einsum("mi,mi->m", q, np.take(self.stride, patch, axis=0)).astype(np.intp)
        cell += self.first_cell[patch]
        reach = radius / size + np.sqrt(np.einsum("mi,mi->m", x, x))  # in cells
        bins = np.minimum(np.ceil(reach * (_CELL_PITCHES / _BIN_PITCHES)).astype(np.intp), self.num_bins - 1)
        return self.list_start[cell], np.take(self.counts, cell * self.num_bins + bins).astype(np.intp)


def _press_kernel(out, sensordata, xpos, xmat, force_idx, patch_of_slot, body_ids, contact_radius,
                  floor_over_a2, origin, cell_size, stride, last, first_cell, list_start, counts,
                  num_bins, bins_per_cell, order, taxel_xyz, num_taxels, threshold, noise, seed,
                  table):  # pragma: no cover (compiled)
    """`TactileModel._press_numpy` and the threshold and noise as one compiled loop.

    Loops over (env, contact slot, candidate) with the same model and float32 arithmetic
    per candidate as the numpy path; no temporaries, so the cost is the candidates' count
    alone (about 5x faster than the numpy version at 64-256 envs). Each env's pressed
    taxels are listed as they are first pressed; threshold and noise (`counter_normal`,
    same draws) then visit that list, not the whole row.
    """
    pressed = np.empty(num_taxels, np.int64)
    local = np.empty(3)
    noise32 = np.float32(noise)
    for env in range(sensordata.shape[0]):
        row = env * num_taxels
        num_pressed = 0
        for slot in range(force_idx.shape[0]):
            f = sensordata[env, force_idx[slot]]
            if f <= 0.0:
                continue
            p = patch_of_slot[slot]
            b = body_ids[p]
            # contact point in the link frame: R^T (c - x)
            c0 = sensordata[env, force_idx[slot] + 3] - xpos[env, b, 0]
            c1 = sensordata[env, force_idx[slot] + 4] - xpos[env, b, 1]
            c2 = sensordata[env, force_idx[slot] + 5] - xpos[env, b, 2]
            for i in range(3):
                local[i] = xmat[env, b, i] * c0 + xmat[env, b, 3 + i] * c1 + xmat[env, b, 6 + i] * c2
            radius = contact_radius[p] * np.cbrt(f)
            # the candidate list (see _CandidateGrid.lookup)
            size = cell_size[p]
            cell = first_cell[p]
            s2 = 0.0
            for i in range(3):
                x = (local[i] - origin[p, i]) / size
                q = min(max(np.rint(x), 0.0), last[p, i])
                s2 += (x - q) * (x - q)
                cell += int(q * stride[p, i])
            reach = radius / size + np.sqrt(s2)
            bins = min(int(np.ceil(reach * bins_per_cell)), num_bins - 1)
            first = list_start[cell]
            count = counts[cell * num_bins + bins]
            if count == 0:
                continue
            a2 = np.float32(radius * radius)
            l0, l1, l2 = np.float32(local[0]), np.float32(local[1]), np.float32(local[2])
            total = np.float32(0.0)
            for j in range(first, first + count):
                t = order[j]
                d0, d1, d2 = taxel_xyz[0, t] - l0, taxel_xyz[1, t] - l1, taxel_xyz[2, t] - l2
                u = a2 - d0 * d0 - d1 * d1 - d2 * d2
                if u > 0:
                    total += np.sqrt(u)
            scale = np.float32(f / max(total, floor_over_a2[p] * a2 * radius))
            for j in range(first, first + count):
                t = order[j]
                d0, d1, d2 = taxel_xyz[0, t] - l0, taxel_xyz[1, t] - l1, taxel_xyz[2, t] - l2
                u = a2 - d0 * d0 - d1 * d1 - d2 * d2
                if u > 0:
                    before = out[row + t]
                    out[row + t] = before + np.sqrt(u) * scale
                    if before == 0 and out[row + t] > 0:
                        pressed[num_pressed] = t
                        num_pressed += 1
        for k in range(num_pressed):
            i = row + pressed[k]
            v = out[i]
            if v < threshold:
                v = np.float32(0.0)
            elif noise32 > 0:
                z = np.uint64(i) * _GOLDEN + seed  # counter_normal's hash
                z = (z ^ (z >> np.uint64(30))) * _MIX1
                z = (z ^ (z >> np.uint64(27))) * _MIX2
                z = z ^ (z >> np.uint64(31))
                v = v * (np.float32(1.0) + noise32 * table[z >> _TABLE_SHIFT])
                v = max(v, np.float32(0.0))
            out[i] = v


class LazyKernel:
    """`fn` compiled by numba at its first use (cached on disk), or None where numba is missing: the
    caller then takes its numpy path, which stays the reference the kernel is tested against."""

    def __init__(self, fn: Any):
        self.fn = fn
        self._kernel: Any = False  # False: not compiled yet; None: numba is missing

    def get(self) -> Any:
        if self._kernel is False:
            try:
                import numba
            except ImportError:
                self._kernel = None
            else:
                self._kernel = numba.njit(cache=True, nogil=True)(self.fn)
        return self._kernel


_press = LazyKernel(_press_kernel)


class TactileModel:
    """Turns link poses and contact sensor data of N envs into taxel readings and positions.

    Args:
        layout: the skin.
        model: a compiled model that has the skin's sensors (see `add_skin_sensors`).

    Shapes (N envs, T taxels, P patches, K contacts per patch):
        positions(xpos (N, nbody, 3), xmat (N, nbody, 9)) -> (N, T, 3) world, float32
        readings(sensordata (N, nsensordata), xpos, xmat, rng) -> (N, T) newtons, float32
    """

    use_compiled: bool = True  # False: the numpy path (the reference the kernel is tested against)

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
        self._taxel_xyz = self.local_positions.T.copy()  # (3, T): one contiguous row per axis
        self._radius = np.array([p.contact_radius for p in patches])
        self._floor_over_a2 = np.array([EDGE_FLOOR * 2 * np.pi / (3.0 * p.pitch**2) for p in patches])  # k E / a^2
        self._grid = _CandidateGrid(layout)
        # gather indices of all slots' (normal force, position) in the sensordata row
        slot = np.arange(self.contacts_per_patch) * SLOT_SIZE
        base = self.sensor_adr[:, None] + slot[None, :]  # (P, K)
        self._force_idx = base + 1
        self._pos_idx = base[..., None] + 4 + np.arange(3)
        self._force_idx_flat = self._force_idx.ravel()
        self._patch_of_slot = np.repeat(np.arange(len(patches)), self.contacts_per_patch)
        # positions: per patch, its columns of the (N, 3T) output and the (12, 3 n_p) matrix
        # that maps a link pose [R (row-major) | x] to its taxels' world coordinates
        offsets = layout.offsets()
        self._pose_maps = [
            (slice(3 * offsets[p], 3 * offsets[p + 1]),
             np.vstack([np.einsum("ik,tj->ijtk", np.eye(3), x).reshape(9, -1),
                        np.tile(np.eye(3), len(x))]).astype(np.float32))
            for p, x in enumerate(local)
        ]

    def contacts(self, sensordata: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Normal forces (N, P, K) and world contact points (N, P, K, 3) from sensordata."""
        return sensordata[:, self._force_idx], sensordata[:, self._pos_idx]

    def positions(self, xpos: np.ndarray, xmat: np.ndarray) -> np.ndarray:
        """World positions (N, T, 3) of all taxels: x_link + R_link p_local.

        One small GEMM per patch and block of envs, [R | x] (n, 12) @ (12, 3 n_p), written
        straight into the output.
        """
        n = xpos.shape[0]
        pose = np.concatenate([np.take(xmat, self.body_ids, axis=1), np.take(xpos, self.body_ids, axis=1)],
                              axis=2).astype(np.float32)  # (N, P, 12)
        out = np.empty((n, 3 * self.num_taxels), np.float32)
        for start in range(0, n, _GEMM_ROWS):
            envs = slice(start, start + _GEMM_ROWS)
            for p, (columns, pose_map) in enumerate(self._pose_maps):
                np.matmul(pose[envs, p], pose_map, out=out[envs, columns])
        return out.reshape(n, self.num_taxels, 3)

    def readings(self, sensordata: np.ndarray, xpos: np.ndarray, xmat: np.ndarray,
                 rng: np.random.Generator | None = None) -> np.ndarray:
        """Taxel readings (N, T): each contact's normal force spread over its patch."""
        n = sensordata.shape[0]
        out = np.zeros(n * self.num_taxels, np.float32)
        noise = self.layout.noise if rng is not None else 0.0
        seed = draw_step_seed(rng) if rng is not None and noise > 0 else np.uint64(0)
        kernel = _press.get() if self.use_compiled else None
        if kernel is not None:
            g = self._grid
            kernel(out, np.ascontiguousarray(sensordata, np.float64), np.ascontiguousarray(xpos, np.float64),
                   np.ascontiguousarray(xmat, np.float64), self._force_idx_flat, self._patch_of_slot,
                   self.body_ids, self._radius, self._floor_over_a2, g.origin, g.cell_size, g.stride, g.last,
                   g.first_cell, g.list_start, g.counts, g.num_bins, _CELL_PITCHES / _BIN_PITCHES, g.order,
                   self._taxel_xyz, self.num_taxels, np.float32(self.layout.threshold), float(noise), seed,
                   normal_table())
            return out.reshape(n, self.num_taxels)
        self._press_numpy(out, sensordata, xpos, xmat)
        # Threshold and noise touch only the pressed taxels (a few % of the array)
        index = np.flatnonzero(out > 0)
        values = np.take(out, index)
        values[values < self.layout.threshold] = 0.0  # readings below the threshold read 0
        if noise > 0:
            values *= 1.0 + noise * counter_normal(seed, index)
            np.maximum(values, 0.0, out=values)
        out[index] = values
        return out.reshape(n, self.num_taxels)

    def _press_numpy(self, out: np.ndarray, sensordata: np.ndarray, xpos: np.ndarray, xmat: np.ndarray) -> None:
        """Add the readings of all contacts to `out` (N * T,), one entry per (contact, candidate taxel)."""
        force_idx = self._force_idx.ravel()
        force = np.take(sensordata, force_idx, axis=1)  # (N, P * K)
        hit = np.flatnonzero(force > 0)
        if len(hit) == 0:
            return
        env, slot = np.divmod(hit, len(force_idx))
        patch = self._patch_of_slot[slot]
        f = np.take(force, hit)
        link = env * xpos.shape[1] + self.body_ids[patch]
        rot = np.take(xmat.reshape(-1, 9), link, axis=0).reshape(-1, 3, 3)
        point = np.take(sensordata, (env * sensordata.shape[1] + force_idx[slot] + 3)[:, None] + np.arange(3))
        # contact point in the link frame: R^T (c - x)
        local = np.einsum("mji,mj->mi", rot, point - np.take(xpos.reshape(-1, 3), link, axis=0))
        radius = self._radius[patch] * np.cbrt(f)
        first, count = self._grid.lookup(patch, local, radius)
        total = int(count.sum())
        if total == 0:
            return
        start = np.cumsum(count) - count
        index = np.repeat(first - start, count)
        index += np.arange(total)
        taxel = np.take(self._grid.order, index).astype(np.intp)
        # u = sqrt(max(0, a^2 - d^2)) = a w per (contact, candidate); the 1/a cancels below
        local = local.astype(np.float32)
        a2 = radius * radius
        u = np.repeat(a2.astype(np.float32), count)
        for axis in range(3):
            diff = np.take(self._taxel_xyz[axis], taxel)
            diff -= np.repeat(local[:, axis], count)
            diff *= diff
            u -= diff
        np.maximum(u, 0.0, out=u)
        np.sqrt(u, out=u)
        # f_i = F u_i / max(sum u, k E a); a contact without candidates gets a stray sum
        # here, but has no entries to scale
        total_u = np.add.reduceat(u, np.minimum(start, total - 1))
        scale = f / np.maximum(total_u, self._floor_over_a2[patch] * a2 * radius)
        u *= np.repeat(scale.astype(np.float32), count)
        np.add.at(out, np.repeat(env * self.num_taxels, count) + taxel, u)
