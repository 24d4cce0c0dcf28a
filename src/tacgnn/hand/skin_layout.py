"""Declarative layout of the tactile skin: which link carries which grid of taxels.

A skin is a list of patches. A patch is a grid of taxels fixed to one link (a body
of the model) and laid on one of two surfaces, given in that link's frame:

* ``plane``: a flat pad. Rows advance along ``row_axis``, columns along
  ``normal x row_axis``; ``row_counts`` lets rows hold fewer taxels than ``cols``
  (the palm), aligned by ``align``.
* ``capsule``: a rounded fingertip. The capsule axis is the link's +z through
  ``origin`` (the start of the straight part); rows advance along the profile by
  arc length from ``arc_start``, first up the straight part of length
  ``length`` and then over the hemispherical cap; columns go around the axis,
  centred on the ``normal`` direction, one ``pitch`` of arc apart.

The default layout is the paper's 653-taxel skin on the Allegro-type hand built by
`tacgnn.hand.allegro`, in the authors' vector order: palm (113); index, middle and
ring as tip (12x6), middle phalanx (6x6), proximal phalanx (6x6); thumb tip (12x6)
and pad (6x6). To describe another skin, write another `SkinLayout` (in Python or
YAML via `tacgnn.config.from_dict`); nothing else needs to change.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from tacgnn.config import check

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class Patch:
    """One grid of taxels on one link. Lengths in metres, in the link's frame."""

    name: str
    body: str
    surface: Literal["plane", "capsule"]
    rows: int
    cols: int
    pitch: float
    origin: Vec3
    normal: Vec3 = (1.0, 0.0, 0.0)
    row_axis: Vec3 = (0.0, 0.0, 1.0)
    row_counts: tuple[int, ...] = ()
    align: Literal["start", "center", "end"] = "center"
    radius: float = 0.0
    length: float = 0.0
    arc_start: float = 0.0
    contact_radius: float = 0.004
    """Radius (m) of the skin's pressed area under a 1 N contact; grows as F^(1/3)."""

    def __post_init__(self) -> None:
        key = f"skin.{self.name}"
        check(self.rows > 0 and self.cols > 0, key, "rows and cols must be positive")
        check(self.pitch > 0, f"{key}.pitch", f"must be positive, got {self.pitch}")
        check(self.contact_radius > 0, f"{key}.contact_radius", "must be positive")
        if self.row_counts:
            check(len(self.row_counts) == self.rows, f"{key}.row_counts",
                  f"needs {self.rows} entries, got {len(self.row_counts)}")
            check(all(0 < c <= self.cols for c in self.row_counts), f"{key}.row_counts",
                  f"each count must be in 1..{self.cols}")
        n = np.asarray(self.normal, float)
        check(abs(np.linalg.norm(n) - 1) < 1e-6, f"{key}.normal", "must be a unit vector")
        if self.surface == "plane":
            r = np.asarray(self.row_axis, float)
            check(abs(np.linalg.norm(r) - 1) < 1e-6 and abs(n @ r) < 1e-6, f"{key}.row_axis",
                  "must be a unit vector perpendicular to the normal")
        else:
            check(self.radius > 0 and self.length >= 0, f"{key}.radius",
                  "a capsule needs radius > 0 and length >= 0")
            check(abs(n[2]) < 1e-6, f"{key}.normal", "must be perpendicular to the capsule axis (z)")
            top = self.arc_start + (self.rows - 1) * self.pitch
            check(self.arc_start >= 0 and top <= self.length + self.radius * np.pi / 2 + 1e-9,
                  f"{key}.rows", f"the last row lies {top:.4f} m along the profile, beyond the cap's top "
                  f"({self.length + self.radius * np.pi / 2:.4f} m): its taxels would leave the link's surface")

    @property
    def size(self) -> int:
        """Number of taxels in this patch."""
        return sum(self.row_counts) if self.row_counts else self.rows * self.cols

    def grid_cells(self) -> np.ndarray:
        """(size, 2) integer (row, col) of each taxel, in the patch's vector order."""
        cells = []
        for i in range(self.rows):
            count = self.row_counts[i] if self.row_counts else self.cols
            first = {"start": 0, "end": self.cols - count, "center": (self.cols - count) // 2}[self.align]
            cells += [(i, first + j) for j in range(count)]
        return np.asarray(cells, dtype=np.int64)

    def local_positions(self) -> tuple[np.ndarray, np.ndarray]:
        """Rest positions and outward normals of the taxels, (size, 3) each, link frame."""
        return self.surface_points(self.grid_cells().astype(float))

    def surface_points(self, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Points and outward normals, (n, 3) each, link frame, at (row, col) grid coordinates.

        Whole coordinates are the taxels; fractional ones lie between them, so the area a
        patch covers is rows and columns in [-0.5, count - 0.5].
        """
        cells = np.asarray(cells, float)
        u = (cells[:, 0] - (self.rows - 1) / 2) * self.pitch
        v_steps = cells[:, 1] - (self.cols - 1) / 2
        origin = np.asarray(self.origin, float)
        normal = np.asarray(self.normal, float)
        if self.surface == "plane":
            row_axis = np.asarray(self.row_axis, float)
            col_axis = np.cross(normal, row_axis)
            pos = origin + u[:, None] * row_axis + (v_steps * self.pitch)[:, None] * col_axis
            return pos, np.tile(normal, (len(pos), 1))
        # capsule: arc length s along the profile, angle phi around the axis
        axis = np.array([0.0, 0.0, 1.0])
        side = np.cross(axis, normal)
        s = self.arc_start + cells[:, 0] * self.pitch
        theta = np.clip((s - self.length) / self.radius, 0.0, np.pi / 2)  # latitude on the cap
        phi = v_steps * self.column_angle(theta)
        radial = np.cos(phi)[:, None] * normal + np.sin(phi)[:, None] * side
        out = np.cos(theta)[:, None] * radial + np.sin(theta)[:, None] * axis
        centre_z = np.minimum(s, self.length)
        axis_point = np.asarray([origin[0], origin[1], 0.0]) + (origin[2] + centre_z)[:, None] * axis
        return axis_point + self.radius * out, out

    def column_angle(self, theta: np.ndarray) -> np.ndarray:
        """Angle (rad) between neighbouring columns of a capsule patch at cap latitude `theta`.

        Columns stay one pitch of arc apart on every row: on the cap the circles of latitude
        shrink, so the angle grows (at most a full turn shared by the columns). A fixed angle
        bunched the cap's last rows to a fifth of the pitch.
        """
        ring = np.maximum(self.radius * np.cos(theta), 1e-9)
        return np.minimum(self.pitch / ring, 2 * np.pi / self.cols)


@dataclass(frozen=True)
class SkinLayout:
    """All patches of a skin, in vector order; taxel i of the skin is found by offset."""

    patches: tuple[Patch, ...]
    threshold: float = 0.0005
    """Readings below this force (N) are set to 0, as in the authors' simulation."""
    noise: float = 0.1
    """Relative (multiplicative, Gaussian) noise on each activated reading; 0 turns it off."""

    def __post_init__(self) -> None:
        check(len(self.patches) > 0, "skin.patches", "a skin needs at least one patch")
        names = [p.name for p in self.patches]
        check(len(set(names)) == len(names), "skin.patches", f"patch names repeat: {names}")
        check(self.threshold >= 0, "skin.threshold", "must be >= 0")
        check(self.noise >= 0, "skin.noise", "must be >= 0")

    @property
    def num_taxels(self) -> int:
        return sum(p.size for p in self.patches)

    def offsets(self) -> np.ndarray:
        """Start index of each patch in the skin vector, plus the total at the end."""
        return np.concatenate([[0], np.cumsum([p.size for p in self.patches])])

    def patch_index(self) -> np.ndarray:
        """(num_taxels,) index of the patch each taxel belongs to."""
        return np.repeat(np.arange(len(self.patches)), [p.size for p in self.patches])

    def grid_cells(self) -> np.ndarray:
        """(num_taxels, 2) (row, col) of each taxel in its patch."""
        return np.concatenate([p.grid_cells() for p in self.patches])

    def with_pitch_scale(self, scale: float) -> SkinLayout:
        """The same patches with taxels `scale` times as far apart (another sensor design)."""
        return replace(self, patches=tuple(replace(p, pitch=p.pitch * scale) for p in self.patches))


# --- The paper's skin on the Allegro-type hand -------------------------------------------

FINGERTIP_PITCH = 0.0026
PHALANX_PITCH = 0.004
PALM_PITCH = 0.00725
PALM_COLUMN_COUNTS = (15, 15, 15, 15, 13, 6, 6, 6, 6, 5, 4, 7)

# Contact radius at 1 N = 1.05 pitches: a typical ball contact of the Baoding task (1.5 N, the
# median over the ground-truth policy's episodes, experiments/faithful_hand/audit.py) then
# presses a disc of radius 1.2 pitches, which holds 4-5 taxels of a square grid
# (pi * 1.2^2 = 4.5), the paper's figure. tests/test_tactile.py measures it.
TYPICAL_CONTACT_FORCE = 1.5
CONTACT_RADIUS_PITCHES = 1.2 / TYPICAL_CONTACT_FORCE ** (1 / 3)
TIP_CONTACT_RADIUS = CONTACT_RADIUS_PITCHES * FINGERTIP_PITCH
PHALANX_CONTACT_RADIUS = CONTACT_RADIUS_PITCHES * PHALANX_PITCH
PALM_CONTACT_RADIUS = CONTACT_RADIUS_PITCHES * PALM_PITCH


def _finger_patches(finger: str, tip_length: float, tip_z0: float, pad_z: dict[str, float]) -> list[Patch]:
    tip = Patch(
        name=f"{finger}_tip", body=f"{finger}_distal", surface="capsule", rows=12, cols=6,
        pitch=FINGERTIP_PITCH, origin=(0.0, 0.0, tip_z0), normal=(1.0, 0.0, 0.0),
        radius=0.012, length=tip_length, arc_start=0.004, contact_radius=TIP_CONTACT_RADIUS,
    )
    pads = [
        Patch(name=f"{finger}_{link}", body=f"{finger}_{link}", surface="plane", rows=6, cols=6,
              pitch=PHALANX_PITCH, origin=(0.0098, 0.0, z), contact_radius=PHALANX_CONTACT_RADIUS)
        for link, z in pad_z.items()
    ]
    return [tip, *pads]


def default_skin() -> SkinLayout:
    """The paper's 653-taxel skin, in the authors' vector order."""
    palm = Patch(
        name="palm", body="palm", surface="plane", rows=12, cols=15, pitch=PALM_PITCH,
        origin=(0.0111, 0.0, -0.004 - 11 * PALM_PITCH / 2), normal=(1.0, 0.0, 0.0),
        row_axis=(0.0, 0.0, -1.0), row_counts=PALM_COLUMN_COUNTS, align="start",
        contact_radius=PALM_CONTACT_RADIUS,
    )
    patches = [palm]
    for finger in ("index", "middle", "ring"):
        patches += _finger_patches(finger, tip_length=0.020, tip_z0=0.009,
                                   pad_z={"medial": 0.0192, "proximal": 0.027})
    patches += _finger_patches("thumb", tip_length=0.016, tip_z0=0.027, pad_z={"medial": 0.0257})
    return SkinLayout(patches=tuple(patches))

