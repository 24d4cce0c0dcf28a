"""ROS 1 bags of the hand's topics, written and read with the `rosbags` package (no ROS needed).

What `tacgnn real-hand record-steps`, `record-skin` and `run --record` write, and what
`tacgnn sysid`, `tacgnn calibrate-skin` and `replay_run` read (each of those decodes the
messages itself: this module knows bags, not the hand, and imports nothing of tacgnn):

* step recordings: the joint states as received and the joint commands as sent; sample
  t of the `JointRecording` is command t with the newest joint state received before it;
* skin recordings: the skin messages as received, one raw frame each;
* runs: per control tick that commanded, the joint state and skin message the tick used,
  the command it sent, all stamped with the tick's time, and the episode starts
  (``std_msgs/Int32`` on the episode topic), so `replay_run` can feed a fresh controller
  exactly what the live one saw.

Messages are stored in the ROS 1 wire format with their definitions, so ``rosbag`` and
any other ROS 1 tool read these bags too.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

JOINT_STATE_TYPE = "sensor_msgs/JointState"
EPISODE_TYPE = "std_msgs/Int32"


class BagError(ValueError):
    """A bag is missing, unreadable or lacks what is needed; the message names file and problem."""


HEADER_DEFINITION = """uint32 seq
time stamp
string frame_id
"""
"""std_msgs/Header, as ROS 1 spells it in a message's full definition."""


def tactile_definition(fields: Iterable[tuple[str, str]]) -> str:
    """The full definition of a skin message: a header, then one float32 array per patch field.

    Used when the skin's message package is not installed (the simulated hand): it must
    match the publisher's definition for ROS to connect them. The header's stamp is the
    instant of the frame, so a controller can pair it with the joint state of the same
    instant. Fields in name order, so the definition depends on which fields there are,
    not on which patch reads which.
    """
    body = "Header header\n" + "".join(f"float32[] {attr}\n" for attr in sorted({attr for _, attr in fields}))
    return body + "=" * 80 + "\nMSG: std_msgs/Header\n" + HEADER_DEFINITION


def _store_name(msgtype: str) -> str:
    """'pkg/Type' -> rosbags' 'pkg/msg/Type'."""
    pkg, _, name = msgtype.partition("/")
    return msgtype if name.startswith("msg/") else f"{pkg}/msg/{name}"


def _typestore(extra: dict[str, str] | None = None):
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    for msgtype, definition in (extra or {}).items():
        name = _store_name(msgtype)
        if name not in store.types:
            store.register(get_types_from_msg(definition, name))
    return store


def _default_message(store, name: str, fields: dict | None = None) -> Any:
    from rosbags.interfaces import Nodetype

    values = dict(fields or {})
    for fname, (kind, detail) in store.fielddefs[name][1]:
        if fname in values:
            continue
        if kind == Nodetype.NAME:
            values[fname] = _default_message(store, detail)
        elif kind == Nodetype.BASE:
            values[fname] = "" if detail[0] == "string" else (False if detail[0] == "bool" else 0)
        else:  # arrays and sequences: empty (fixed-size arrays of numbers: zeros)
            (item_kind, item), size = detail
            numeric = item_kind == Nodetype.BASE and item[0] not in ("string", "bool")
            values[fname] = np.zeros(size if kind == Nodetype.ARRAY else 0, dtype=item[0]) if numeric else []
    return store.types[name](**values)


class BagWriter:
    """Appends messages to a new ROS 1 bag: rospy messages as they are, or plain values by type.

    Use as a context manager; `write_msg` takes a rospy (genpy) message, `write` a
    rosbags message object of a registered type (see `message`).
    """

    def __init__(self, path: str | Path, definitions: dict[str, str] | None = None):
        from rosbags.rosbag1 import Writer

        self.path = Path(path)
        if self.path.suffix != ".bag":
            raise BagError(f"bag {self.path}: the file name must end in .bag")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if self.path.exists():
            self.path.unlink()
        self.store = _typestore(definitions)
        self._writer = Writer(self.path)
        self._writer.open()
        self._connections: dict[str, Any] = {}

    def _connection(self, topic: str, msgtype: str, msgdef: str | None = None, md5: str | None = None):
        if topic not in self._connections:
            if msgdef is None:
                msgdef, md5 = self.store.generate_msgdef(_store_name(msgtype))
            self._connections[topic] = self._writer.add_connection(topic, _store_name(msgtype), msgdef=msgdef,
                                                                   md5sum=md5)
        return self._connections[topic]

    def message(self, msgtype: str, **fields) -> Any:
        """A message object of `msgtype` ('pkg/Type'), unset fields at their defaults (0, '', empty)."""
        return _default_message(self.store, _store_name(msgtype), fields)

    def write(self, topic: str, msgtype: str, msg: Any, time_s: float) -> None:
        data = self.store.serialize_ros1(msg, _store_name(msgtype))
        self._writer.write(self._connection(topic, msgtype), int(round(time_s * 1e9)), bytes(data))

    def write_msg(self, topic: str, msg: Any, time_s: float) -> None:
        """A rospy message, stored as it came over the wire (its own definition and md5)."""
        import io

        buf = io.BytesIO()
        msg.serialize(buf)
        conn = self._connection(topic, msg._type, msg._full_text, msg._md5sum)
        self._writer.write(conn, int(round(time_s * 1e9)), buf.getvalue())

    def close(self) -> None:
        self._writer.close()

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass(frozen=True)
class BagMessage:
    topic: str
    time: float
    """Bag time (s)."""
    msg: Any


def read_bag(path: str | Path, topics: dict[str, str]) -> dict[str, list[BagMessage]]:
    """Messages of the needed topics, in time order per topic.

    Args:
        topics: what for -> topic name, e.g. ``{"joint states": "/allegroHand_0/joint_states"}``;
            a topic the bag lacks raises `BagError` naming it, its use and what the bag holds.
    """
    from rosbags.rosbag1 import Reader

    path = Path(path)
    if not path.is_file():
        raise BagError(f"bag {path}: file not found")
    try:
        reader = Reader(path)
        reader.open()
    except Exception as err:
        raise BagError(f"bag {path}: not a readable ROS 1 bag ({type(err).__name__}: {err})") from err
    try:
        present = {c.topic for c in reader.connections}
        missing = [f"{topic} ({use})" for use, topic in topics.items() if topic not in present]
        if missing:
            raise BagError(f"bag {path}: no messages on {', '.join(missing)}; the bag holds topics "
                           f"{sorted(present) or 'none'}")
        wanted = [c for c in reader.connections if c.topic in topics.values()]
        store = _typestore({c.msgtype: c.msgdef.data for c in wanted})
        out: dict[str, list[BagMessage]] = {t: [] for t in topics.values()}
        for conn, stamp, raw in reader.messages(connections=wanted):
            out[conn.topic].append(BagMessage(conn.topic, stamp * 1e-9, store.deserialize_ros1(raw, conn.msgtype)))
    finally:
        reader.close()
    return out
