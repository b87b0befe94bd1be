"""What every reader returns, the one protocol every bag format's reader follows, and how a
source's kind is recognized (docs/ingest.md#formats)."""

from __future__ import annotations

import sqlite3
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.progress import Progress
from qsls.pipeline.ingest.sources.layout import Batch

ROS1_MAGIC = b"#ROSBAG V2.0\n"
MCAP_MAGIC = b"\x89MCAP0\r\n"
SQLITE_MAGIC = b"SQLite format 3\x00"
ULOG_MAGIC = b"ULog\x01\x12\x35"

METADATA = "metadata.yaml"
"""A rosbag2 folder's listing of its storage files and topics."""

KINDS = ("ros1", "rosbag2", "db3", "mcap", "ulog", "tum", "euroc")
BAG_HINT = (
    "give a ROS1 .bag, a rosbag2 folder (or its .db3/.mcap file), a plain .mcap, "
    "a PX4 ULog (.ulg), a TUM trajectory or a EuRoC ground-truth csv"
)


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a source: name, ROS2-style message type, message count."""

    topic: str
    msgtype: str
    count: int
    source: Path


@dataclass(frozen=True)
class Trajectory:
    """One stream as arrays, in the order the source stored it (not yet sorted).

    ``velocity`` is the message's linear velocity as stored (an Odometry twist: in the child
    frame by the ROS convention), ``None`` when the message type has none. ``pose_var`` and
    ``twist_var`` are the diagonals ``(n, 6)`` of an Odometry's pose covariance (``x y z``
    in ``frame_id``, then the rotation about its ``x y z`` axes) and twist covariance
    (linear ``x y z``, angular ``x y z``, in ``child_frame_id``), as recorded; ``None`` when
    the type has none or every one of them is zero (ROS: unknown).
    """

    name: str
    msgtype: str
    header_ns: np.ndarray  # int64 (n,)
    log_ns: np.ndarray  # int64 (n,)
    position: np.ndarray  # (n, 3)
    orientation: np.ndarray  # (n, 4) x y z w
    velocity: np.ndarray | None
    frame_id: str = ""
    child_frame_id: str = ""
    decoder: str = ""  # "numpy" | "deserializer" | "text"
    pose_var: np.ndarray | None = None
    twist_var: np.ndarray | None = None
    source: str = ""
    """Where the stream was read from (a bag or file path; empty for a stream built in
    memory), as the manifest names it."""

    def __len__(self) -> int:
        return len(self.header_ns)


RawTopic = tuple[list[bytes], list[int], Any]
"""One topic's raw messages, their log stamps and its schema (None unless the format has one)."""

IndexPlan = tuple[dict[str, set[int]], Callable[[], Iterable[Batch]]]
"""``({topic: its connection labels in Batch.conn}, the batches)``: a topic read through the
bag's own index."""


class BagReader(Protocol):
    """One bag format's reader, opened on ``path`` (``READERS`` in
    :mod:`qsls.pipeline.ingest.sources.bags` maps a detected kind to it); the format-free
    part of a read (decoding, counts, errors) is :class:`~qsls.pipeline.ingest.sources.bags.BagSource`'s."""

    path: Path
    cdr: bool
    """Messages are CDR (ROS 2, MCAP), not ROS1."""
    listed_by: str
    """Where the topics' types come from, as an error names it (``the bag``, ``its metadata.yaml``)."""

    def topics(self) -> list[TopicInfo]:
        """Every topic, its type and message count, in any order."""
        ...

    def indexed(self, infos: list[TopicInfo]) -> IndexPlan | None:
        """The fixed-layout topics ``infos`` through the bag's own index (:data:`IndexPlan`);
        None when the format or this bag has no such path (compressed messages, say)."""
        ...

    def raw(self, infos: list[TopicInfo], progress: Progress) -> dict[str, RawTopic]:
        """``{topic: (raw messages, log stamps, schema)}`` of ``infos`` in one pass."""
        ...

    def deserialize(self, info: TopicInfo, raws: list[bytes], schema: Any) -> list[Any]:
        """The messages ``raws`` of ``info`` as message objects (a per-message deserializer)."""
        ...

    def close(self) -> None: ...


_REPAIR = {
    "ros1": "rosbag reindex BAG",
    "mcap": "mcap recover IN.mcap -o OUT.mcap",  # a plain MCAP: the mcap CLI, no metadata.yaml
}


def damaged_hint(kind: str) -> str:
    """What to do about a truncated or damaged bag of ``kind`` (detect()'s names)."""
    tool = _REPAIR.get(kind, "ros2 bag reindex BAG_FOLDER")
    return (
        "it looks truncated or damaged; if the recording was cut off, repair it "
        f"('{tool}') and try again"
    )


def locked_hint(exc: BaseException) -> str | None:
    """What to do about an sqlite3 database another program holds locked (None: not that)."""
    if isinstance(exc, sqlite3.OperationalError) and "locked" in str(exc).lower():
        return (
            "the bag's database is locked by another program (a recorder still writing it?); "
            "wait for it to finish, or copy the bag folder, and try again"
        )
    return None


def _head(path: Path, n: int = 16) -> bytes:
    with open(path, "rb") as fh:
        return fh.read(n)


def detect(path: Path) -> str:
    """The kind of ``path``: one of ``KINDS``; a one-line :class:`InputError` otherwise."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file or folder; check the path")
    if path.is_dir():
        if (path / METADATA).is_file():
            return "rosbag2"
        raise InputError(f"{path}: folder without metadata.yaml is not a rosbag2 bag; {BAG_HINT}")
    if path.stat().st_size == 0:
        raise InputError(f"{path}: the file is empty; record or export the log again")
    head = _head(path)
    if head.startswith(ROS1_MAGIC[:9]):
        if not head.startswith(ROS1_MAGIC):
            raise InputError(f"{path}: ROS1 bag version {head[9:12]!r} is not supported (2.0 is)")
        return "ros1"
    if head.startswith(MCAP_MAGIC[:5]):
        return "rosbag2" if _listed_in_metadata(path) else "mcap"
    if head.startswith(SQLITE_MAGIC):
        return "rosbag2" if _listed_in_metadata(path) else "db3"
    if head.startswith(ULOG_MAGIC):
        return "ulog"
    return _text_kind(path)


def _listed_in_metadata(path: Path) -> bool:
    meta = path.parent / METADATA
    return meta.is_file() and path.name in meta.read_text(errors="replace")


def bag_root(path: Path) -> Path:
    """The rosbag2 folder of a path that is the folder or a storage file listed in it."""
    path = Path(path)
    return path if path.is_dir() else path.parent


def _text_kind(path: Path) -> str:
    with open(path, "rb") as fh:
        raw = fh.read(4096)
    not_text = f"{path}: not a bag and not a trajectory text file; {BAG_HINT}"
    if b"\x00" in raw:
        raise InputError(not_text)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise InputError(not_text) from None
    words = False
    for line in text.splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        if line[0].isalpha():  # a csv header line; more than a few of them: not a trajectory
            words = True
            continue
        parts = line.split(",") if "," in line else line.split()
        try:
            [float(p) for p in parts]
        except ValueError:
            raise InputError(not_text) from None
        if "," in line and len(parts) >= 8:
            return "euroc"
        if "," not in line and len(parts) == 8:
            return "tum"
        raise InputError(
            f"{path}: a text line with {len(parts)} fields is neither TUM "
            "('t x y z qx qy qz qw') nor EuRoC csv ('t_ns, px, py, pz, qw, qx, qy, qz, ...')"
        )
    if words:
        raise InputError(not_text)
    raise InputError(f"{path}: no data lines; the trajectory file is empty")
