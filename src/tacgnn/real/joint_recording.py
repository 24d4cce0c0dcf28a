"""Recordings of joint position steps, the input of system identification.

A recording is what the hand did under a sequence of position commands, sampled at the
control rate (50 Hz on the Allegro hand). Sample t holds the joint angles measured at
``time[t]`` and the targets sent right after that measurement, in force until ``time[t+1]``.
The replay (`tacgnn.real.sysid`) starts at rest at ``measured[0]``, so start recording
with the hand still.

Three file formats, the same content:

``.bag`` (ROS 1, what ``tacgnn real-hand record-steps`` writes): the joint states as
    received on ``/allegroHand_0/joint_states`` and the commands as sent on
    ``/allegroHand_0/joint_cmd`` (``sensor_msgs/JointState``, driver joint names); sample t
    is command t with the newest joint state received before it.

``.npz`` (numpy): arrays
    ``time``      (T,)    seconds, strictly increasing, evenly spaced
    ``target``    (T, 16) commanded joint positions, rad
    ``measured``  (T, 16) measured joint positions, rad
    and optionally ``true_stiffness``, ``true_damping`` (16,) when a simulator made the
    recording (`tacgnn sysid --make-recording`): the answer identification should find.

``.csv``: a header row naming the columns ``time``, ``target_<joint>`` and
    ``measured_<joint>`` for the 16 joints of `tacgnn.hand.allegro.JOINT_NAMES`
    (``target_index_j0``, ..., ``measured_thumb_j3``), in any order; one row per sample;
    lines starting with ``#`` are comments.

Joints are in the Allegro driver's order: index j0-j3, middle, ring, thumb.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tacgnn.files import atomic_write, atomic_write_text
from tacgnn.hand.allegro import JOINT_NAMES, NUM_JOINTS
from tacgnn.real.bag import BagError, read_bag
from tacgnn.real.messages import decode_joint_state
from tacgnn.real.ros_config import RosConfig

MAX_PERIOD_JITTER = 0.25
"""Largest allowed |dt - median dt| / median dt: the replay steps at one fixed period."""


class RecordingError(ValueError):
    """A recording file is missing, unreadable or malformed; the message names file and problem."""


@dataclass(frozen=True, eq=False)
class JointRecording:
    """Validated arrays of one recording (see the module docstring for their meaning)."""

    time: np.ndarray
    target: np.ndarray
    measured: np.ndarray
    true_stiffness: np.ndarray | None = None
    true_damping: np.ndarray | None = None
    source: str = "<memory>"

    def __post_init__(self) -> None:
        _validate(self)

    @property
    def num_samples(self) -> int:
        return len(self.time)

    @property
    def period(self) -> float:
        """The control period (s): the median spacing of the time stamps."""
        return float(np.median(np.diff(self.time)))


def _fail(source: str, problem: str) -> None:
    raise RecordingError(f"recording {source}: {problem}")


def _validate(rec: JointRecording) -> None:
    src = rec.source
    arrays = {"time": rec.time, "target": rec.target, "measured": rec.measured}
    for name, value in arrays.items():
        if not isinstance(value, np.ndarray) or not np.issubdtype(value.dtype, np.number):
            _fail(src, f"array '{name}' must be numeric, got {getattr(value, 'dtype', type(value).__name__)}")
    if rec.time.ndim != 1 or len(rec.time) < 2:
        _fail(src, f"array 'time' must have shape (T,) with T >= 2 samples, got shape {rec.time.shape}")
    t = len(rec.time)
    for name in ("target", "measured"):
        if arrays[name].shape != (t, NUM_JOINTS):
            _fail(src, f"array '{name}' must have shape ({t}, {NUM_JOINTS}) (samples x joints, like 'time'), "
                       f"got {arrays[name].shape}")
    for name, value in arrays.items():
        bad = ~np.isfinite(value)
        if bad.any():
            row = int(np.argwhere(bad)[0][0])
            where = f"sample {row}" if value.ndim == 1 else \
                f"sample {row}, joint {JOINT_NAMES[int(np.argwhere(bad)[0][1])]}"
            _fail(src, f"array '{name}' has {int(bad.sum())} non-finite values (NaN/Inf), first at {where}")
    dt = np.diff(rec.time)
    if (dt <= 0).any():
        _fail(src, f"'time' must increase strictly; it does not after sample {int(np.argmax(dt <= 0))}")
    period = float(np.median(dt))
    jitter = float(np.max(np.abs(dt - period))) / period
    if jitter > MAX_PERIOD_JITTER:
        _fail(src, f"samples are not evenly spaced (period {period:.4f} s, worst deviation "
                   f"{100 * jitter:.0f} %): resample to a fixed rate first")
    for name in ("true_stiffness", "true_damping"):
        value = getattr(rec, name)
        if value is not None and (np.shape(value) != (NUM_JOINTS,) or not np.isfinite(value).all()):
            _fail(src, f"optional array '{name}' must hold {NUM_JOINTS} finite values, got shape {np.shape(value)}")


def load_recording(path: str | Path) -> JointRecording:
    """Read and validate a .npz or .csv recording; RecordingError names the file and the problem."""
    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"recording {path}: file not found")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        arrays = _read_npz(path)
    elif suffix == ".csv":
        arrays = _read_csv(path)
    elif suffix == ".bag":
        return _read_bag(path)
    else:
        raise RecordingError(f"recording {path}: unknown format '{suffix}' (use .bag, .npz or .csv)")
    return JointRecording(**arrays, source=str(path))


def _read_bag(path: Path) -> JointRecording:
    """A ROS 1 bag of `tacgnn real-hand record-steps`, on the Allegro driver's default topics."""
    ros = RosConfig()
    try:
        return joint_recording_from_bag(path, ros.joint_state_topic, ros.joint_cmd_topic, ros.joint_names)
    except BagError as err:
        raise RecordingError(str(err)) from err


def joint_recording_from_bag(path: str | Path, joint_state_topic: str, command_topic: str,
                             joint_names: tuple[str, ...]) -> JointRecording:
    """The `JointRecording` of a step bag: each command with the newest joint state before it."""
    msgs = read_bag(path, {"joint states": joint_state_topic, "joint commands": command_topic})
    states, commands = msgs[joint_state_topic], msgs[command_topic]
    state_times = np.array([m.time for m in states])
    times, targets, measured = [], [], []
    for cmd in commands:
        i = np.searchsorted(state_times, cmd.time, side="right") - 1
        if i < 0:
            continue  # commands before the first joint state have nothing measured
        try:
            measured.append(decode_joint_state(states[i].msg, joint_names)[0])
            targets.append(decode_joint_state(cmd.msg, joint_names)[0])
        except ValueError as err:
            raise RecordingError(f"recording {path}: {err}") from err
        times.append(cmd.time)
    if len(times) < 2:
        raise RecordingError(f"recording {path}: fewer than 2 commands after the first joint state")
    t = np.asarray(times)
    return JointRecording(t - t[0], np.asarray(targets), np.asarray(measured), source=str(path))


def _read_npz(path: Path) -> dict:
    try:
        with np.load(path, allow_pickle=False) as data:
            contents = {k: data[k] for k in data.files}
    except Exception as err:  # zip errors, pickled objects, truncated files
        raise RecordingError(f"recording {path}: not a readable .npz file ({type(err).__name__}: {err})") from err
    missing = [k for k in ("time", "target", "measured") if k not in contents]
    if missing:
        raise RecordingError(f"recording {path}: missing array(s) {missing}; the file holds {sorted(contents)}")
    out = {k: np.asarray(contents[k]) for k in ("time", "target", "measured")}
    for k in ("true_stiffness", "true_damping"):
        if k in contents:
            out[k] = np.asarray(contents[k], dtype=np.float64)
    return {k: v.astype(np.float64) if np.issubdtype(v.dtype, np.number) else v for k, v in out.items()}


def csv_columns() -> list[str]:
    """The CSV header: time, then the 16 targets, then the 16 measured angles."""
    return ["time", *(f"target_{j}" for j in JOINT_NAMES), *(f"measured_{j}" for j in JOINT_NAMES)]


def _read_csv(path: Path) -> dict:
    text = "".join(line for line in path.read_text().splitlines(keepends=True) if not line.lstrip().startswith("#"))
    rows = list(csv.reader(io.StringIO(text)))
    rows = [r for r in rows if any(cell.strip() for cell in r)]
    if not rows:
        raise RecordingError(f"recording {path}: empty CSV file")
    header = [c.strip() for c in rows[0]]
    missing = [c for c in csv_columns() if c not in header]
    if missing:
        shown = ", ".join(missing[:4]) + (f" and {len(missing) - 4} more" if len(missing) > 4 else "")
        raise RecordingError(f"recording {path}: missing column(s) {shown}; expected header: "
                             f"time, target_<joint>, measured_<joint> for joints {', '.join(JOINT_NAMES[:2])}, ...")
    try:
        values = np.array([[float(c) for c in r] for r in rows[1:]], dtype=np.float64)
    except ValueError as err:
        raise RecordingError(f"recording {path}: a cell is not a number ({err})") from err
    if values.ndim != 2 or values.shape[1] != len(header):
        raise RecordingError(f"recording {path}: every row needs {len(header)} cells, like the header")
    col = {name: i for i, name in enumerate(header)}
    return {
        "time": values[:, col["time"]],
        "target": values[:, [col[f"target_{j}"] for j in JOINT_NAMES]],
        "measured": values[:, [col[f"measured_{j}"] for j in JOINT_NAMES]],
    }


def save_recording(rec: JointRecording, path: str | Path) -> Path:
    """Write `rec` as .npz or .csv (by the file's suffix)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    suffix = path.suffix.lower()
    if suffix == ".npz":
        extra = {k: getattr(rec, k) for k in ("true_stiffness", "true_damping") if getattr(rec, k) is not None}
        atomic_write(path, lambda fh: np.savez(fh, time=rec.time, target=rec.target, measured=rec.measured, **extra))
    elif suffix == ".csv":
        table = np.concatenate([rec.time[:, None], rec.target, rec.measured], axis=1)
        text = io.StringIO(newline="")
        text.write("# tacgnn joint recording: time s, targets and measured joint angles rad\n")
        writer = csv.writer(text)
        writer.writerow(csv_columns())
        writer.writerows([[repr(float(v)) for v in row] for row in table])
        atomic_write_text(path, text.getvalue())
    else:
        raise RecordingError(f"recording {path}: unknown format '{suffix}' (use .npz or .csv)")
    return path
