"""What a bag writer records: streams of poses, odometry, images and mavros setpoints, and
their messages.

Every format's writer (:mod:`.ros1.writer`, :mod:`.rosbag2.writer`, :mod:`.mcap.writer`,
chosen by :func:`qsls.pipeline.ingest.sources.write.write_bag`) takes the same streams and
builds each message with :class:`MessageBuilder` through rosbags' typestore (ROS1 Noetic or
ROS2 Humble types, :mod:`.msgtypes`): nothing lays out bytes by hand. Messages of all
streams are written in ``log_ns`` order (stable: ties keep stream order,
:func:`log_order`). docs/ingest.md#formats.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from qsls.pipeline.ingest.sources.msgtypes import (
    ATTITUDE_TARGET,
    IMAGE,
    ODOMETRY,
    POSE_COV,
    POSE_STAMPED,
    POSE_TYPES,
    POSITION_TARGET,
    TF,
    TRANSFORM,
    typestore,
)


def _arr(a: Any, shape: tuple[int, ...], dtype: Any = float) -> np.ndarray:
    out = np.asarray(a, dtype=dtype)
    if out.shape != shape:
        raise ValueError(f"expected shape {shape}, got {out.shape}")
    return out


@dataclass(frozen=True)
class OdometryStream:
    """A ``nav_msgs/msg/Odometry`` topic (what a VIO estimator publishes).

    ``linear_velocity`` and ``angular_velocity`` are expressed in the child frame (the body,
    ROS convention); ``orientation`` is the quaternion ``x, y, z, w`` of the child frame in
    ``frame_id``.
    """

    topic: str
    header_ns: np.ndarray
    log_ns: np.ndarray
    position: np.ndarray
    orientation: np.ndarray
    linear_velocity: np.ndarray
    angular_velocity: np.ndarray | None = None
    frame_id: str = "odom"
    child_frame_id: str = "base_link"
    pose_covariance: np.ndarray | None = None
    """``(n, 36)`` row-major 6x6 pose covariances (``x y z``, rotation about ``x y z``), or
    None: zeros (ROS: unknown)."""
    twist_covariance: np.ndarray | None = None
    """``(n, 36)`` twist covariances (linear, angular), or None: zeros."""

    @property
    def msgtype(self) -> str:
        return ODOMETRY

    def __len__(self) -> int:
        return len(self.header_ns)


@dataclass(frozen=True)
class PoseStream:
    """A pose topic: ``msgtype`` is one of ``POSE_TYPES``.

    ``nav_msgs/msg/Odometry`` is written with zero twist; ``tf2_msgs/msg/TFMessage`` with
    one transform ``frame_id -> child_frame_id`` per message (several streams may share a
    ``/tf`` topic to interleave frames).
    """

    topic: str
    header_ns: np.ndarray
    log_ns: np.ndarray
    position: np.ndarray
    orientation: np.ndarray
    msgtype: str = POSE_STAMPED
    frame_id: str = "world"
    child_frame_id: str = "body"

    def __len__(self) -> int:
        return len(self.header_ns)


@dataclass(frozen=True)
class ImageStream:
    """A ``sensor_msgs/msg/Image`` topic of pseudo-random ``mono8`` frames (benchmarks).

    Frame ``i`` is a window of one seeded noise buffer, so content varies per frame (it
    compresses like camera data, not like zeros) without generating gigabytes of noise.
    """

    topic: str
    header_ns: np.ndarray
    log_ns: np.ndarray
    height: int = 480
    width: int = 640
    frame_id: str = "camera"
    seed: int = 0
    _noise: np.ndarray = field(init=False, repr=False, compare=False)

    @property
    def msgtype(self) -> str:
        return IMAGE

    def __post_init__(self) -> None:
        rng = np.random.default_rng(self.seed)
        size = self.height * self.width
        # smooth-ish noise: low 5 bits random, like a textured scene with sensor noise
        noise = (rng.integers(0, 32, size=2 * size, dtype=np.uint8) + 96).astype(np.uint8)
        object.__setattr__(self, "_noise", noise)

    def pixels(self, i: int) -> np.ndarray:
        size = self.height * self.width
        start = (i * 7919) % size
        return self._noise[start : start + size]

    def __len__(self) -> int:
        return len(self.header_ns)


@dataclass(frozen=True)
class AttitudeTargetStream:
    """A ``mavros_msgs/msg/AttitudeTarget`` topic (``/mavros/setpoint_raw/attitude`` or its
    echo ``target_attitude``): ``orientation`` ``(n, 4)`` ``x, y, z, w``, the FLU body in ENU;
    ``thrust`` ``(n,)`` normalized (float32 in the message); ``body_rate`` zeros and ignored
    (``type_mask`` 7: the three rates) unless given."""

    topic: str
    header_ns: np.ndarray
    log_ns: np.ndarray
    orientation: np.ndarray
    thrust: np.ndarray
    type_mask: int = 7
    frame_id: str = ""

    @property
    def msgtype(self) -> str:
        return ATTITUDE_TARGET

    def __len__(self) -> int:
        return len(self.header_ns)


@dataclass(frozen=True)
class PositionTargetStream:
    """A ``mavros_msgs/msg/PositionTarget`` topic (``/mavros/setpoint_raw/local``):
    ``position``, ``velocity``, ``acceleration`` ``(n, 3)`` in ``coordinate_frame`` (1,
    ``FRAME_LOCAL_NED``: mavros' name for the ENU local frame on the ROS side), ``yaw``
    ``(n,)`` rad; ``type_mask`` 2048 (the yaw rate ignored) unless given."""

    topic: str
    header_ns: np.ndarray
    log_ns: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    yaw: np.ndarray
    coordinate_frame: int = 1
    type_mask: int = 2048
    frame_id: str = ""

    @property
    def msgtype(self) -> str:
        return POSITION_TARGET

    def __len__(self) -> int:
        return len(self.header_ns)


Stream = OdometryStream | PoseStream | ImageStream | AttitudeTargetStream | PositionTargetStream


# --------------------------------------------------------------------------- messages
class MessageBuilder:
    """Build typestore message objects for one ROS version."""

    def __init__(self, ros1: bool) -> None:
        self.ros1 = ros1
        self.ts = typestore(ros1)
        t = self.ts.types
        self.Time = t["builtin_interfaces/msg/Time"]
        self.Header = t["std_msgs/msg/Header"]
        self.Point = t["geometry_msgs/msg/Point"]
        self.Vector3 = t["geometry_msgs/msg/Vector3"]
        self.Quaternion = t["geometry_msgs/msg/Quaternion"]
        self.Pose = t["geometry_msgs/msg/Pose"]
        self.PoseCov = t["geometry_msgs/msg/PoseWithCovariance"]
        self.Twist = t["geometry_msgs/msg/Twist"]
        self.TwistCov = t["geometry_msgs/msg/TwistWithCovariance"]
        self.Transform = t["geometry_msgs/msg/Transform"]
        self.types = t
        self.zero36 = np.zeros(36, dtype=np.float64)

    def serialize(self, msg: Any, msgtype: str) -> bytes:
        if self.ros1:
            return bytes(self.ts.serialize_ros1(msg, msgtype))
        return bytes(self.ts.serialize_cdr(msg, msgtype))

    def header(self, ns: int, frame_id: str, seq: int) -> Any:
        sec, nsec = divmod(int(ns), 1_000_000_000)
        stamp = self.Time(sec=sec, nanosec=nsec)
        if self.ros1:
            return self.Header(seq=seq, stamp=stamp, frame_id=frame_id)
        return self.Header(stamp=stamp, frame_id=frame_id)

    def quat(self, q: np.ndarray) -> Any:
        return self.Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))

    def pose(self, p: np.ndarray, q: np.ndarray) -> Any:
        return self.Pose(
            position=self.Point(x=float(p[0]), y=float(p[1]), z=float(p[2])),
            orientation=self.quat(q),
        )

    def vec(self, v: np.ndarray) -> Any:
        return self.Vector3(x=float(v[0]), y=float(v[1]), z=float(v[2]))

    def write_all(self, writer: Any, streams: Sequence[Stream]) -> None:
        """Every message of ``streams`` through an open rosbags writer (``rosbag1`` or
        ``rosbag2``), one connection per topic, in log-time order (:func:`log_order`)."""
        conns = {
            t: writer.add_connection(t, mt, typestore=self.ts)
            for t, mt in stream_types(streams).items()
        }
        for k, i, log in log_order(streams):
            s = streams[k]
            writer.write(conns[s.topic], log, self.serialize(self.message(s, i), s.msgtype))

    def message(self, s: Stream, i: int) -> Any:
        mt = s.msgtype
        hdr = self.header(s.header_ns[i], s.frame_id, i)
        if isinstance(s, ImageStream):
            return self.types[IMAGE](
                header=hdr,
                height=s.height,
                width=s.width,
                encoding="mono8",
                is_bigendian=0,
                step=s.width,
                data=s.pixels(i),
            )
        if isinstance(s, AttitudeTargetStream):
            return self.types[ATTITUDE_TARGET](
                header=hdr,
                type_mask=s.type_mask,
                orientation=self.quat(s.orientation[i]),
                body_rate=self.vec(np.zeros(3)),
                thrust=float(s.thrust[i]),
            )
        if isinstance(s, PositionTargetStream):
            p = s.position[i]
            return self.types[POSITION_TARGET](
                header=hdr,
                coordinate_frame=s.coordinate_frame,
                type_mask=s.type_mask,
                position=self.Point(x=float(p[0]), y=float(p[1]), z=float(p[2])),
                velocity=self.vec(s.velocity[i]),
                acceleration_or_force=self.vec(s.acceleration[i]),
                yaw=float(s.yaw[i]),
                yaw_rate=0.0,
            )
        pose = self.pose(s.position[i], s.orientation[i])
        if mt == ODOMETRY:
            pcov = tcov = self.zero36
            if isinstance(s, OdometryStream):
                lin = s.linear_velocity[i]
                ang = s.angular_velocity[i] if s.angular_velocity is not None else np.zeros(3)
                if s.pose_covariance is not None:
                    pcov = np.asarray(s.pose_covariance[i], dtype=np.float64)
                if s.twist_covariance is not None:
                    tcov = np.asarray(s.twist_covariance[i], dtype=np.float64)
            else:
                lin = ang = np.zeros(3)
            return self.types[ODOMETRY](
                header=hdr,
                child_frame_id=s.child_frame_id,
                pose=self.PoseCov(pose=pose, covariance=pcov),
                twist=self.TwistCov(
                    twist=self.Twist(linear=self.vec(lin), angular=self.vec(ang)),
                    covariance=tcov,
                ),
            )
        if mt == POSE_STAMPED:
            return self.types[POSE_STAMPED](header=hdr, pose=pose)
        if mt == POSE_COV:
            return self.types[POSE_COV](
                header=hdr, pose=self.PoseCov(pose=pose, covariance=self.zero36)
            )
        tr = self.types[TRANSFORM](
            header=hdr,
            child_frame_id=s.child_frame_id,
            transform=self.Transform(
                translation=self.vec(s.position[i]), rotation=pose.orientation
            ),
        )
        if mt == TRANSFORM:
            return tr
        if mt == TF:
            return self.types[TF](transforms=[tr])
        raise ValueError(f"unsupported message type {mt!r}; use one of {', '.join(POSE_TYPES)}")


def check_streams(streams: Sequence[Stream]) -> None:
    """Refuse arrays of the wrong shape and message types no writer has (``ValueError``)."""
    for s in streams:
        n = len(s.header_ns)
        _arr(s.log_ns, (n,), np.int64)
        if isinstance(s, ImageStream):
            continue
        if isinstance(s, AttitudeTargetStream):
            _arr(s.orientation, (n, 4))
            _arr(s.thrust, (n,))
            continue
        if isinstance(s, PositionTargetStream):
            for a in (s.position, s.velocity, s.acceleration):
                _arr(a, (n, 3))
            _arr(s.yaw, (n,))
            continue
        _arr(s.position, (n, 3))
        _arr(s.orientation, (n, 4))
        if isinstance(s, OdometryStream):
            _arr(s.linear_velocity, (n, 3))
            if s.angular_velocity is not None:
                _arr(s.angular_velocity, (n, 3))
            for cov in (s.pose_covariance, s.twist_covariance):
                if cov is not None:
                    _arr(cov, (n, 36))
        elif s.msgtype not in POSE_TYPES:
            raise ValueError(f"{s.topic}: unsupported message type {s.msgtype!r}")


def log_order(streams: Sequence[Stream]) -> Iterator[tuple[int, int, int]]:
    """(stream index, message index, log_ns) in log-time order, stable across streams."""
    if not streams:
        return iter(())
    sid = np.concatenate([np.full(len(s), k, dtype=np.int64) for k, s in enumerate(streams)])
    mid = np.concatenate([np.arange(len(s), dtype=np.int64) for s in streams])
    log = np.concatenate([np.asarray(s.log_ns, dtype=np.int64) for s in streams])
    order = np.lexsort((mid, sid, log))
    return zip(sid[order].tolist(), mid[order].tolist(), log[order].tolist(), strict=True)


def stream_types(streams: Sequence[Stream]) -> dict[str, str]:
    """``{topic: message type}`` of ``streams`` (a topic has one type)."""
    topics: dict[str, str] = {}
    for s in streams:
        if topics.setdefault(s.topic, s.msgtype) != s.msgtype:
            raise ValueError(f"topic {s.topic} given with two message types")
    return topics
