"""Read a mavros user's bag: the controller's attitude setpoints and the reference it tracked.

docs/vehicle.md#what-to-log. Any bag format (ROS1, rosbag2 sqlite3 or MCAP, plain MCAP),
through :class:`~qsls.pipeline.ingest.sources.bags.BagSource`'s per-message path (rosbags'
typestore holds mavros' types, :mod:`.msgtypes`). Public:

- :func:`read_bag_commands`: a ``mavros_msgs/AttitudeTarget`` topic
  (``/mavros/setpoint_raw/target_attitude``, the echo of what PX4 was sent, or
  ``/mavros/setpoint_raw/attitude``, the command) as
  :class:`~qsls.pipeline.ingest.sources.ulog.reader.AttitudeCommands`: ``q`` the message's
  ``orientation`` (already the FLU body in ENU, ``[x, y, z, w]``), ``thrust`` its normalized
  thrust; a bag states no hover thrust (``hover_thrust`` NaN, ``hover_source`` ``none``);
- :func:`read_bag_setpoints`: a ``mavros_msgs/PositionTarget`` topic as
  :class:`~qsls.pipeline.ingest.sources.ulog.reader.PositionSetpoints` (ENU as written; a
  field the ``type_mask`` ignores is NaN);
- :func:`first_topic`: the first of several topic names a bag holds.

Stamps (``t_ns``): the header stamps, the controller's tick; a topic with a message whose
stamp was left at zero is timed by its bag log time instead (when the recorder got it, a
transport later than the tick: stamp the messages).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.progress import NULL_PROGRESS
from qsls.pipeline.ingest.sources.bags import BagSource
from qsls.pipeline.ingest.sources.base import TopicInfo
from qsls.pipeline.ingest.sources.msgtypes import ATTITUDE_TARGET, POSITION_TARGET
from qsls.pipeline.ingest.sources.ulog.reader import AttitudeCommands, PositionSetpoints

COMMAND_TOPICS = ("/mavros/setpoint_raw/attitude", "/mavros/setpoint_raw/target_attitude")
"""Where the attitude setpoints are looked for, in order (``--commands-topic`` names another)."""
REFERENCE_TOPICS = ("/qsls/reference", "/mavros/setpoint_raw/local")
"""Where the reference is looked for, in order (``--reference-topic`` names another)."""

FRAME_LOCAL_NED = 1
"""``PositionTarget.coordinate_frame`` of the local frame (ENU on mavros' ROS side)."""
IGNORE_P, IGNORE_V, IGNORE_A, FORCE = 0b111, 0b111000, 0b111000000, 512
"""``PositionTarget.type_mask`` bits: position, velocity, acceleration ignored; a force."""
IGNORE_THRUST, IGNORE_ATTITUDE = 64, 128
"""``AttitudeTarget.type_mask`` bits."""

RECORD_HINT = (
    "record the controller's attitude setpoints (mavros_msgs/AttitudeTarget: "
    "/mavros/setpoint_raw/target_attitude, or the command /mavros/setpoint_raw/attitude) and "
    "the reference it tracked (mavros_msgs/PositionTarget, one per tick, e.g. /qsls/reference), "
    "or name them with --commands-topic / --reference-topic"
)


@dataclass(frozen=True)
class Stamped:
    """A topic's messages, sorted by ``t_ns`` (header stamps, else log times)."""

    topic: str
    messages: list[Any]
    t_ns: np.ndarray


def _listing(topics: Sequence[TopicInfo]) -> str:
    kinds = ", ".join(f"{t.topic} ({t.msgtype.rsplit('/', 1)[-1]})" for t in topics)
    return kinds or "none"


def first_topic(path: Path, wanted: Sequence[str], what: str) -> str:
    """The first of ``wanted`` that ``path`` holds; a one-line :class:`InputError` naming the
    bag's topics and what to record when it holds none (``what``: the role, for the message)."""
    path = Path(path)
    with BagSource(path) as bag:
        topics = bag.topics()
    have = {t.topic for t in topics}
    for name in wanted:
        if name in have:
            return name
    raise InputError(
        f"{path.name} has no {what} topic ({' or '.join(wanted)}); its topics: "
        f"{_listing(topics)}; {RECORD_HINT}"
    )


def _read(path: Path, topic: str, msgtype: str) -> Stamped:
    """The messages of ``topic`` (of type ``msgtype``) with their stamps (module docstring)."""
    path = Path(path)
    with BagSource(path) as bag:
        topics = bag.topics()
        info = next((t for t in topics if t.topic == topic), None)
        if info is None:
            raise InputError(f"{path.name} has no topic {topic}; its topics: {_listing(topics)}")
        if info.msgtype != msgtype:
            raise InputError(
                f"{path.name}: {topic} is {info.msgtype}, not {msgtype}; {RECORD_HINT}"
            )
        reader = bag.reader
        assert reader is not None
        try:
            raws, logs, schema = reader.raw([info], NULL_PROGRESS)[topic]
            msgs = reader.deserialize(info, raws, schema)
        except InputError:
            raise
        except Exception as exc:
            what = " ".join(str(exc).split()) or type(exc).__name__
            raise InputError(
                f"{path}: cannot read {topic} ({what}); the bag may be damaged"
            ) from None
    header = np.array(
        [int(m.header.stamp.sec) * 1_000_000_000 + int(m.header.stamp.nanosec) for m in msgs],
        dtype=np.int64,
    )
    t = header if (header > 0).all() else np.asarray(logs, dtype=np.int64)
    order = np.argsort(t, kind="stable")
    return Stamped(topic, [msgs[i] for i in order], t[order])


def _xyz(msgs: list[Any], field: str) -> np.ndarray:
    out = np.empty((len(msgs), 3))
    for i, m in enumerate(msgs):
        v = getattr(m, field)
        out[i] = (v.x, v.y, v.z)
    return out


def read_bag_commands(path: Path, topic: str) -> AttitudeCommands:
    """The attitude setpoints of ``topic`` in ``path`` (module docstring). A setpoint whose ``type_mask`` ignores the attitude or
    the thrust (a rate command) is refused: its input is not in the message."""
    got = _read(path, topic, ATTITUDE_TARGET)
    msgs = got.messages
    mask = np.array([int(m.type_mask) for m in msgs], dtype=np.int64)
    bad = (mask & (IGNORE_ATTITUDE | IGNORE_THRUST)) != 0
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise InputError(
            f"{Path(path).name}: {topic} message {k} ignores its attitude or thrust (type_mask "
            f"{int(mask[k])}): a rate command's input is not in the log; the controller must "
            "send an attitude and a thrust"
        )
    q = np.array([(m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w)
                  for m in msgs], dtype=float).reshape(-1, 4)  # fmt: skip
    thrust = np.array([float(m.thrust) for m in msgs], dtype=float)
    return AttitudeCommands(
        t_ns=got.t_ns, q=q, thrust=thrust, hover_thrust=np.full(len(msgs), np.nan),
        hover_source="none", thr_mdl_fac=None,
    )  # fmt: skip


def read_bag_setpoints(path: Path, topic: str) -> PositionSetpoints:
    """The reference of ``topic`` in ``path`` (module docstring). A frame other than the local one (a body frame) or an acceleration field holding a force
    is refused: neither is the reference's state."""
    got = _read(path, topic, POSITION_TARGET)
    msgs = got.messages
    frame = np.array([int(m.coordinate_frame) for m in msgs], dtype=np.int64)
    mask = np.array([int(m.type_mask) for m in msgs], dtype=np.int64)
    odd = (frame != FRAME_LOCAL_NED) | ((mask & FORCE) != 0)
    if odd.any():
        k = int(np.flatnonzero(odd)[0])
        raise InputError(
            f"{Path(path).name}: {topic} message {k} has coordinate_frame {int(frame[k])} and "
            f"type_mask {int(mask[k])}: the reference must be a position, velocity and "
            "acceleration in the local frame (FRAME_LOCAL_NED = 1, ENU on the ROS side)"
        )
    p, v, a = _xyz(msgs, "position"), _xyz(msgs, "velocity"), _xyz(msgs, "acceleration_or_force")
    for arr, bits in ((p, IGNORE_P), (v, IGNORE_V), (a, IGNORE_A)):
        arr[(mask & bits) != 0] = np.nan
    yaw = np.array([float(m.yaw) for m in msgs], dtype=float)
    return PositionSetpoints(t_ns=got.t_ns, p=p, v=v, a=a, yaw=yaw)
