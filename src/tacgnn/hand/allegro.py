"""An Allegro-type 16-DoF hand, built in code with `mujoco.MjSpec`.

Dimensions are the Allegro hand's published kinematics (right hand): in the palm
frame z runs along the fingers, +x is the palmar side (fingers flex towards +x) and
+y is the thumb's side. Collision shapes are boxes and capsules (much faster than
meshes). Joint 0 of each finger spreads it sideways (axis: palm normal), joints 1-3
flex it. Each joint is driven by a position actuator with stiffness `stiffness`
and joint damping `damping`, the two parameters system identification fits (one
value for all joints, or 16 per-joint values as `tacgnn sysid` writes them). The
actuator's torque is capped at `torque_limit` (the authors' 0.5 N m per joint): the
policy cannot buy strength the real motors do not have.

The links collide with each other (fingers with fingers, the thumb with the palm);
MuJoCo leaves out parent-child pairs, so adjacent links never touch.

The palm is fixed to the world, palm up: palm +x points to world +z, the fingers
point along world +y, then the hand is tilted by `palm_tilt_deg` about world x
(positive lowers the fingertips). The hand origin (the line of the finger bases)
is the world origin.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import mujoco
import numpy as np

from tacgnn.config import check

FINGERS = ("index", "middle", "ring", "thumb")
LINKS = ("base", "proximal", "medial", "distal")
JOINT_NAMES = tuple(f"{f}_j{k}" for f in FINGERS for k in range(4))
NUM_JOINTS = len(JOINT_NAMES)
"""The hand's joint count (16): the one definition every module imports."""
ACTUATOR_NAMES = tuple(f"{f}_a{k}" for f in FINGERS for k in range(4))

# Joint limits (rad) used by the TacGNN authors for index, middle, ring (j0..j3).
FINGER_RANGES = ((-0.47, 0.47), (-0.196, 1.61), (-0.174, 1.709), (-0.227, 1.618))
# The Allegro thumb's full ranges, and the nearly frozen ranges of the Baoding task.
THUMB_RANGES = ((0.263, 1.396), (-0.105, 1.163), (-0.189, 1.644), (-0.162, 1.719))
THUMB_BAODING_RANGES = ((0.7, 0.9), (0.1, 0.3), (0.8, 0.9), (0.4, 0.6))
DEFAULT_RANGES = FINGER_RANGES * 3 + THUMB_RANGES
#: The least sliding friction a contact may have: below it MuJoCo's solver diverges (measured at 1e-6 in a grasp).
MIN_FRICTION = 1e-4

# Published Allegro geometry (m). Finger bases in the palm frame; 5 deg outward turn
# of index and ring about the palm's x axis.
FINGER_BASES = {
    "index": ((0.0, 0.0435, -0.001542), (0.999048, -0.0436194, 0.0, 0.0)),
    "middle": ((0.0, 0.0, 0.0007), (1.0, 0.0, 0.0, 0.0)),
    "ring": ((0.0, -0.0435, -0.001542), (0.999048, 0.0436194, 0.0, 0.0)),
}
SEGMENT_OFFSETS = (0.0164, 0.054, 0.0384)  # base->proximal->medial->distal joints
THUMB_BASE = ((-0.0182, 0.019333, -0.045987), (0.477714, -0.521334, -0.521334, -0.477714))
THUMB_OFFSETS = ((-0.027, 0.005, 0.0399), (0.0, 0.0, 0.0177), (0.0, 0.0, 0.0514))
LINK_HALF_XY = (0.0098, 0.01375)  # link cross-section 0.0196 x 0.0275
# The distal links' boxes are narrowed to lie inside the skinned fingertip capsule
# (sqrt(2) x 0.0084 < TIP_RADIUS): a full-width box's edges stood out of the capsule where
# the tip's taxels are, so a ball touched the bare box and the skin missed the contact.
DISTAL_HALF_XY = (0.0084, 0.0084)
PALM_HALF = (0.0204, 0.0565, 0.0475)
PALM_CENTRE = (-0.0093, 0.0, -0.0475)
PALM_MASS = 0.415
# The palm's collision shape: the full width from the finger bases down to PALM_NOTCH_Z; below
# it (the heel) the thumb's side is cut back to PALM_NOTCH_Y, where the real hand carries the
# thumb's motor module and no skin. A full box there overlaps the thumb's proximal link by up
# to 10 mm in the Baoding pose.
PALM_NOTCH_Z = -0.037
PALM_NOTCH_Y = 0.03
TIP_RADIUS = 0.012

# Geom collision classes: hand links touch objects and each other (adjacent links are
# parent and child, which MuJoCo excludes); objects touch the hand and each other.
HAND_CONTYPE, HAND_CONAFFINITY = 1, 3
OBJECT_CONTYPE, OBJECT_CONAFFINITY = 2, 3


@dataclass(frozen=True)
class HandConfig:
    """Physical parameters of the hand."""

    stiffness: float | tuple[float, ...] = 3.0
    """Position-actuator gain kp (N m/rad); the authors' system identification grid is {1, 3, 5}.
    One value for every joint, or 16 per-joint values in JOINT_NAMES order."""
    damping: float | tuple[float, ...] = 0.1
    """Joint damping (N m s/rad); identification grid {0, 0.1, 0.5}. One value or 16."""
    torque_limit: float | tuple[float, ...] = 0.5
    """Largest torque each actuator applies (N m): the authors' Isaac Gym hand caps every joint
    at 0.5 N m, the figure their policies transferred to the real hand with (docs/environment.md).
    One value or 16."""
    armature: float = 0.001
    """Reflected motor inertia per joint (kg m^2); keeps the stiff joints stable at 5 ms steps."""
    joint_ranges: tuple[tuple[float, float], ...] = DEFAULT_RANGES
    """(low, high) in rad for the 16 joints: index j0-j3, middle, ring, thumb."""
    target_ranges: tuple[tuple[float, float], ...] = ()
    """(low, high) in rad the 16 position targets are clipped to, inside `joint_ranges`: a software
    limit on the commands, as a real hand's driver can set, that keeps a policy's strokes shorter
    than the joints allow. Empty: the joint ranges. Actions still map onto `joint_ranges`."""
    palm_tilt_deg: float = 15.0
    """Tilt of the palm-up hand about world x; positive lowers the fingertips."""
    friction: float = 1.0
    """Sliding friction of the hand's surfaces."""
    link_density: float = 800.0
    """Density of the finger links (kg/m^3)."""

    def __post_init__(self) -> None:
        check(len(self.joint_ranges) == NUM_JOINTS, "hand.joint_ranges",
              f"needs {NUM_JOINTS} (low, high) pairs, got {len(self.joint_ranges)}")
        for name, (lo, hi) in zip(JOINT_NAMES, self.joint_ranges):
            check(lo < hi, "hand.joint_ranges", f"joint {name} has low {lo} >= high {hi}")
        if self.target_ranges:
            check(len(self.target_ranges) == NUM_JOINTS, "hand.target_ranges",
                  f"needs {NUM_JOINTS} (low, high) pairs or none, got {len(self.target_ranges)}")
            for name, (lo, hi), (jlo, jhi) in zip(JOINT_NAMES, self.target_ranges, self.joint_ranges):
                check(jlo <= lo < hi <= jhi, "hand.target_ranges",
                      f"joint {name}: ({lo}, {hi}) must be increasing and inside its joint range ({jlo}, {jhi})")
        # bounds a simulated finger stays stable and meaningful within (the authors' values: 3, 0.1, 0.5)
        _check_per_joint(self.stiffness, "hand.stiffness", lambda v: 0 < v <= 1000, "in (0, 1000] N m/rad")
        _check_per_joint(self.damping, "hand.damping", lambda v: 0 <= v <= 100, "in [0, 100] N m s/rad")
        _check_per_joint(self.torque_limit, "hand.torque_limit", lambda v: 1e-3 <= v <= 100, "in [0.001, 100] N m")
        # per-joint values as a tuple of floats (hashable, comparable)
        for name in ("stiffness", "damping", "torque_limit"):
            if isinstance(getattr(self, name), (tuple, list)):
                object.__setattr__(self, name, _per_joint(getattr(self, name)))
        check(0 <= self.armature <= 1, "hand.armature", f"must be in [0, 1] kg m^2, got {self.armature}")
        check(-90 <= self.palm_tilt_deg <= 90, "hand.palm_tilt_deg", f"must be in [-90, 90], got {self.palm_tilt_deg}")
        check(MIN_FRICTION <= self.friction <= 100, "hand.friction",
              f"must be in [{MIN_FRICTION}, 100], got {self.friction}")
        check(0 < self.link_density <= 1e5, "hand.link_density", f"must be in (0, 1e5] kg/m^3, got {self.link_density}")

    def joint_target_ranges(self) -> tuple[tuple[float, float], ...]:
        """The 16 (low, high) ranges position targets are clipped to: `target_ranges` or the joint ranges."""
        return self.target_ranges or self.joint_ranges

    def joint_stiffness(self) -> tuple[float, ...]:
        """The 16 actuator gains, whether configured as one value or per joint."""
        return _per_joint(self.stiffness)

    def joint_damping(self) -> tuple[float, ...]:
        """The 16 joint dampings, whether configured as one value or per joint."""
        return _per_joint(self.damping)

    def joint_torque_limit(self) -> tuple[float, ...]:
        """The 16 actuator torque limits (N m), whether configured as one value or per joint."""
        return _per_joint(self.torque_limit)

    def palm_quat(self) -> np.ndarray:
        """World orientation of the palm frame (w, x, y, z)."""
        # palm x -> world z, palm y -> world x, palm z -> world y; then tilt about world x.
        base = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
        a = -np.deg2rad(self.palm_tilt_deg)
        tilt = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, (tilt @ base).flatten())
        return quat


def _per_joint(value: float | tuple[float, ...]) -> tuple[float, ...]:
    return tuple(float(v) for v in value) if isinstance(value, (tuple, list)) else (float(value),) * len(JOINT_NAMES)


def _valid_number(v, ok) -> bool:
    return isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v) and ok(v)


def _check_per_joint(value, key: str, ok, needs: str) -> None:
    """A scalar, or exactly 16 values; each finite and `ok`."""
    if isinstance(value, (tuple, list)):
        check(len(value) == len(JOINT_NAMES), key, f"needs one value or {len(JOINT_NAMES)} per-joint values "
              f"({', '.join(JOINT_NAMES[:2])}, ...), got {len(value)}")
        for name, v in zip(JOINT_NAMES, value):
            check(_valid_number(v, ok), key, f"joint {name}: must be a finite number {needs}, got {v!r}")
    else:
        check(_valid_number(value, ok), key, f"must be a finite number {needs}, got {value!r}")


def _box(body: mujoco.MjsBody, half: tuple, pos: tuple, density: float, name: str) -> None:
    body.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_BOX, size=list(half), pos=list(pos),
                  density=density, contype=HAND_CONTYPE, conaffinity=HAND_CONAFFINITY,
                  rgba=[0.2, 0.2, 0.22, 1.0])


def _link_box(body: mujoco.MjsBody, half_z: float, density: float, name: str,
              half_xy: tuple[float, float] = LINK_HALF_XY) -> None:
    _box(body, (*half_xy, half_z), (0.0, 0.0, half_z), density, name)


def _tip(body: mujoco.MjsBody, half_len: float, z: float, name: str) -> None:
    body.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=[TIP_RADIUS, half_len, 0],
                  pos=[0, 0, z], density=800.0, contype=HAND_CONTYPE,
                  conaffinity=HAND_CONAFFINITY, rgba=[0.9, 0.9, 0.9, 1.0])


def _joint(body: mujoco.MjsBody, name: str, axis: tuple, rng: tuple, cfg: HandConfig) -> None:
    damping = cfg.joint_damping()[JOINT_NAMES.index(name)]
    body.add_joint(name=name, type=mujoco.mjtJoint.mjJNT_HINGE, axis=list(axis), range=list(rng),
                   limited=mujoco.mjtLimited.mjLIMITED_TRUE, damping=damping,
                   armature=cfg.armature)


def add_hand(spec: mujoco.MjSpec, cfg: HandConfig) -> None:
    """Add the hand (bodies, joints, geoms, position actuators) to `spec`'s world."""
    spec.default.geom.friction = [cfg.friction, 0.005, 0.0001]
    palm = spec.worldbody.add_body(name="palm", pos=[0, 0, 0], quat=list(cfg.palm_quat()))
    for name, (y0, y1), (z0, z1) in (
            ("palm_geom", (-PALM_HALF[1], PALM_HALF[1]), (PALM_NOTCH_Z, 0.0)),
            ("palm_heel_geom", (-PALM_HALF[1], PALM_NOTCH_Y), (-2 * PALM_HALF[2], PALM_NOTCH_Z))):
        palm.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_BOX,
                      size=[PALM_HALF[0], (y1 - y0) / 2, (z1 - z0) / 2],
                      pos=[PALM_CENTRE[0], (y0 + y1) / 2, (z0 + z1) / 2],
                      mass=PALM_MASS / 2, contype=HAND_CONTYPE, conaffinity=HAND_CONAFFINITY,
                      rgba=[0.2, 0.2, 0.22, 1.0])
    ranges = dict(zip(JOINT_NAMES, cfg.joint_ranges))
    d = cfg.link_density
    for finger, (pos, quat) in FINGER_BASES.items():
        body = palm.add_body(name=f"{finger}_base", pos=list(pos), quat=list(quat))
        _joint(body, f"{finger}_j0", (1, 0, 0), ranges[f"{finger}_j0"], cfg)
        _link_box(body, 0.0082, d, f"{finger}_base_geom")
        for k, (link, offset) in enumerate(zip(LINKS[1:], SEGMENT_OFFSETS), start=1):
            body = body.add_body(name=f"{finger}_{link}", pos=[0, 0, offset])
            _joint(body, f"{finger}_j{k}", (0, 1, 0), ranges[f"{finger}_j{k}"], cfg)
            half_z = {"proximal": 0.027, "medial": 0.0192, "distal": 0.008}[link]
            _link_box(body, half_z, d, f"{finger}_{link}_geom",
                      DISTAL_HALF_XY if link == "distal" else LINK_HALF_XY)
        _tip(body, 0.010, 0.019, f"{finger}_tip_geom")

    body = palm.add_body(name="thumb_base", pos=list(THUMB_BASE[0]), quat=list(THUMB_BASE[1]))
    _joint(body, "thumb_j0", (-1, 0, 0), ranges["thumb_j0"], cfg)
    _box(body, (0.0179, 0.017, 0.02275), (-0.0179, 0.009, 0.0145), d, "thumb_base_geom")
    axes = ((0, 0, 1), (0, 1, 0), (0, 1, 0))
    halves = (0.00885, 0.0257, 0.0157)
    for k, (link, thumb_offset, axis, half_z) in enumerate(zip(LINKS[1:], THUMB_OFFSETS, axes, halves), start=1):
        body = body.add_body(name=f"thumb_{link}", pos=list(thumb_offset))
        _joint(body, f"thumb_j{k}", axis, ranges[f"thumb_j{k}"], cfg)
        _link_box(body, half_z, d, f"thumb_{link}_geom", DISTAL_HALF_XY if link == "distal" else LINK_HALF_XY)
    _tip(body, 0.008, 0.035, "thumb_tip_geom")

    # The palm is welded to the world, and MuJoCo's parent-child filter does not apply to bodies
    # welded to the world: exclude the palm's pairs with the links mounted on it by hand.
    for child in (*(f"{f}_base" for f in FINGER_BASES), "thumb_base"):
        spec.add_exclude(bodyname1="palm", bodyname2=child)

    for actuator, joint, (lo, hi), kp, limit in zip(ACTUATOR_NAMES, JOINT_NAMES, cfg.joint_target_ranges(),
                                                     cfg.joint_stiffness(), cfg.joint_torque_limit()):
        act = spec.add_actuator(name=actuator, target=joint, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.set_to_position(kp=kp)
        act.ctrlrange = [lo, hi]
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.forcerange = [-limit, limit]
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
