"""Write flight logs as real bags: ROS1, ROS2 (sqlite3 or MCAP storage) and plain MCAP.

Used by the simulator to record its flights, by the tests to write fixtures with known
content, and by the benchmark. Every message goes through the official writers
(``rosbags.rosbag1.Writer``, ``rosbags.rosbag2.Writer``, ``mcap.writer.Writer``) and is
serialized by rosbags' typestore (ROS1 Noetic types for ``ros1``, ROS2 Humble for the
others); nothing here lays out bytes by hand.

Formats (``FORMATS``):

- ``ros1``: one ``.bag`` file (chunk compression ``lz4`` or ``bz2`` optional).
- ``ros2-sqlite`` / ``ros2-mcap``: a rosbag2 folder (``metadata.yaml`` version 9) with one
  ``.db3`` or ``.mcap`` storage file (``zstd`` message compression optional).
- ``mcap``: a single ``.mcap`` file, ``ros2msg`` schemas and ``cdr`` messages, the way
  ``ros2 bag record -s mcap`` and Foxglove write them (chunk compression ``zstd``/``lz4``).

Messages of all streams are written in ``log_ns`` order (stable: ties keep stream order).
The bag appears atomically: it is written under a temporary name beside ``path`` and
renamed into place, replacing an existing bag of the same name.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.core.locks import make_temporary

FORMATS = ("ros1", "ros2-sqlite", "ros2-mcap", "mcap")

ODOMETRY = "nav_msgs/msg/Odometry"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
POSE_COV = "geometry_msgs/msg/PoseWithCovarianceStamped"
TRANSFORM = "geometry_msgs/msg/TransformStamped"
TF = "tf2_msgs/msg/TFMessage"
IMAGE = "sensor_msgs/msg/Image"
POSE_TYPES = (POSE_STAMPED, POSE_COV, TRANSFORM, ODOMETRY, TF)

_COMPRESSIONS = {
    "ros1": (None, "lz4", "bz2"),
    "ros2-sqlite": (None, "zstd"),
    "ros2-mcap": (None, "zstd"),
    "mcap": (None, "zstd", "lz4"),
}


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


Stream = OdometryStream | PoseStream | ImageStream


# --------------------------------------------------------------------------- messages
_TF_MSG = "geometry_msgs/TransformStamped[] transforms\n"


def typestore(ros1: bool) -> Any:
    """rosbags' typestore: ROS1 Noetic (plus ``tf2_msgs/msg/TFMessage``) or ROS2 Humble."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if TF not in ts.types:
        ts.register(get_types_from_msg(_TF_MSG, TF))
    return ts


class _Builder:
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

    def pose(self, p: np.ndarray, q: np.ndarray) -> Any:
        return self.Pose(
            position=self.Point(x=float(p[0]), y=float(p[1]), z=float(p[2])),
            orientation=self.Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])),
        )

    def vec(self, v: np.ndarray) -> Any:
        return self.Vector3(x=float(v[0]), y=float(v[1]), z=float(v[2]))

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


def _check(streams: Sequence[Stream]) -> None:
    for s in streams:
        n = len(s.header_ns)
        _arr(s.log_ns, (n,), np.int64)
        if isinstance(s, ImageStream):
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


def _order(streams: Sequence[Stream]) -> Iterator[tuple[int, int, int]]:
    """(stream index, message index, log_ns) in log-time order, stable across streams."""
    if not streams:
        return iter(())
    sid = np.concatenate([np.full(len(s), k, dtype=np.int64) for k, s in enumerate(streams)])
    mid = np.concatenate([np.arange(len(s), dtype=np.int64) for s in streams])
    log = np.concatenate([np.asarray(s.log_ns, dtype=np.int64) for s in streams])
    order = np.lexsort((mid, sid, log))
    return zip(sid[order].tolist(), mid[order].tolist(), log[order].tolist(), strict=True)


def _stream_types(streams: Sequence[Stream]) -> dict[str, str]:
    topics: dict[str, str] = {}
    for s in streams:
        if topics.setdefault(s.topic, s.msgtype) != s.msgtype:
            raise ValueError(f"topic {s.topic} given with two message types")
    return topics


# --------------------------------------------------------------------------- writers
def _write_ros1(
    path: Path, streams: Sequence[Stream], compression: str | None, chunk_size: int | None
) -> None:
    from rosbags.rosbag1 import Writer

    b = _Builder(ros1=True)
    w = Writer(path)
    if chunk_size:
        w.chunk_threshold = int(chunk_size)
    if compression:
        w.set_compression(Writer.CompressionFormat[compression.upper()])
    with w:
        conns = {
            t: w.add_connection(t, mt, typestore=b.ts) for t, mt in _stream_types(streams).items()
        }
        for k, i, log in _order(streams):
            s = streams[k]
            w.write(conns[s.topic], log, b.serialize(b.message(s, i), s.msgtype))


def _write_ros2(
    path: Path, streams: Sequence[Stream], storage: str, compression: str | None
) -> None:
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

    b = _Builder(ros1=False)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    w = Writer(path, version=9, storage_plugin=plugin)
    if compression:
        w.set_compression(CompressionMode.MESSAGE, CompressionFormat[compression.upper()])
    with w:
        conns = {
            t: w.add_connection(t, mt, typestore=b.ts) for t, mt in _stream_types(streams).items()
        }
        for k, i, log in _order(streams):
            s = streams[k]
            w.write(conns[s.topic], log, b.serialize(b.message(s, i), s.msgtype))


def _write_mcap(
    path: Path, streams: Sequence[Stream], compression: str | None, chunk_size: int | None
) -> None:
    from mcap.writer import CompressionType, Writer

    b = _Builder(ros1=False)
    ctype = CompressionType[compression.upper()] if compression else CompressionType.NONE
    with open(path, "wb") as fh:
        w = Writer(fh, compression=ctype, chunk_size=chunk_size or 1 << 20)
        w.start(profile="ros2", library="qsls")
        channels: dict[str, int] = {}
        for topic, mt in _stream_types(streams).items():
            msgdef, _ = b.ts.generate_msgdef(mt, ros_version=2)
            schema = w.register_schema(name=mt, encoding="ros2msg", data=msgdef.encode())
            channels[topic] = w.register_channel(
                topic=topic, message_encoding="cdr", schema_id=schema
            )
        seq: dict[str, int] = {}
        for k, i, log in _order(streams):
            s = streams[k]
            n = seq.get(s.topic, 0)
            seq[s.topic] = n + 1
            data = b.serialize(b.message(s, i), s.msgtype)
            w.add_message(channels[s.topic], log_time=log, data=data, publish_time=log, sequence=n)
        w.finish()


def write_bag(
    path: Path,
    streams: Sequence[Stream],
    fmt: str,
    *,
    compression: str | None = None,
    chunk_size: int | None = None,
) -> Path:
    """Write ``streams`` into a bag at ``path`` in format ``fmt`` (one of ``FORMATS``).

    ``ros1`` and ``mcap`` give a file, ``ros2-sqlite`` and ``ros2-mcap`` a rosbag2 folder.
    ``chunk_size`` (bytes, ``ros1`` and ``mcap``) overrides the writers' 1 MiB chunks.
    Returns ``path``. Atomic: nothing appears at ``path`` unless the whole bag was written.
    """
    path = Path(path)
    if fmt not in FORMATS:
        raise ValueError(f"unknown bag format {fmt!r}; use one of {', '.join(FORMATS)}")
    if compression not in _COMPRESSIONS[fmt]:
        allowed = ", ".join(c for c in _COMPRESSIONS[fmt] if c)
        raise ValueError(f"compression {compression!r} not available for {fmt}; use {allowed}")
    _check(streams)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmpdir = make_temporary(path)
    tmp = tmpdir / path.name
    try:
        if fmt == "ros1":
            _write_ros1(tmp, streams, compression, chunk_size)
        elif fmt == "mcap":
            _write_mcap(tmp, streams, compression, chunk_size)
        else:
            _write_ros2(tmp, streams, fmt.split("-")[1], compression)
        if path.is_dir():
            shutil.rmtree(path)
        os.replace(tmp, path)
    finally:
        shutil.rmtree(tmpdir, ignore_errors=True)
    return path
