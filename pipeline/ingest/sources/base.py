"""What every reader returns, and how a source's kind is recognized."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from qsls.pipeline.core.errors import InputError

ROS1_MAGIC = b"#ROSBAG V2.0\n"
MCAP_MAGIC = b"\x89MCAP0\r\n"
SQLITE_MAGIC = b"SQLite format 3\x00"

KINDS = ("ros1", "rosbag2", "db3", "mcap", "tum", "euroc")
BAG_HINT = (
    "give a ROS1 .bag, a rosbag2 folder (or its .db3/.mcap file), a plain .mcap, "
    "a TUM trajectory or a EuRoC ground-truth csv"
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

    def __len__(self) -> int:
        return len(self.header_ns)


def _head(path: Path, n: int = 16) -> bytes:
    with open(path, "rb") as fh:
        return fh.read(n)


def detect(path: Path) -> str:
    """The kind of ``path``: one of ``KINDS``; a one-line :class:`InputError` otherwise."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file or folder; check the path")
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
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
    return _text_kind(path)


def _listed_in_metadata(path: Path) -> bool:
    meta = path.parent / "metadata.yaml"
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
