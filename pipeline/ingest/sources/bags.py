"""Read one pose topic of a bag into a :class:`Trajectory`.

Bags are listed and, off the fast paths, read with rosbags (``AnyReader``: ROS1 ``.bag`` and
rosbag2 folders with sqlite3 or MCAP storage) and plain MCAP files with the ``mcap`` package.
The fast paths below read what those libraries expose (rosbags' ROS1 reader and chunk
list, a rosbag2 folder's ``metadata.yaml``, the sqlite3 tables, MCAP's summary and chunk
indexes) and parse by hand only the record heads they check and the fixed-layout
messages.

Decoding, fastest first:

1. ROS1, fixed-layout types (:mod:`qsls.pipeline.ingest.sources.layout`): the bag's message
   index (time, chunk position and offset of every message, read as numpy arrays from its
   index records, :func:`qsls.pipeline.ingest.sources.ros1index.open_ros1`) and rosbags'
   ``Reader.chunks`` (where each chunk's data starts and how it is compressed) give every
   message record's place. Uncompressed chunks are memory-mapped, so only the pages holding the wanted
   records are read (camera images in the same chunks are skipped); compressed chunks
   that hold wanted messages are decompressed once each. The record headers are checked
   (op code, connection id and time equal what the index says) and the message data
   decoded for the whole topic at once. A test checks the sliced bytes against rosbags'
   ``messages()`` byte for byte. rosbags' ROS1 reader is opened with its index read by
   numpy (:func:`qsls.pipeline.ingest.sources.ros1index.open_ros1`); ``AnyReader`` only
   for the per-message path.
2. MCAP (plain, and rosbag2 MCAP storage without message/file compression), fixed-layout
   types (:mod:`qsls.pipeline.ingest.sources.mcapchunks`): the summary's chunk indexes and
   each chunk's message indexes locate every wanted message; uncompressed chunks are
   memory-mapped, zstd/lz4 chunks decompressed once each with the ``mcap`` package's
   helpers, the records checked against the index and decoded for the whole topic at once.
   A test compares them record for record with the ``mcap`` reader.
3. ROS2 sqlite3 without compression, fixed-layout types (:mod:`qsls.pipeline.ingest.sources.sqlite`):
   the topics from ``metadata.yaml`` (:mod:`qsls.pipeline.ingest.sources.listing`, as for
   rosbag2 MCAP folders) and each wanted topic from one aggregate SQL query per database
   file that concatenates the byte ranges holding its fields (:class:`layout.Trim`,
   planned on the topic's first message and checked on every other), decoded at once;
   rosbags' reader is not even opened (its opening scans the whole database to count
   messages and imports a ROS 2 typestore). MCAP without a usable index: raw messages from
   the reader, decoded at once.
4. Anything else (``tf2_msgs/msg/TFMessage``, big-endian CDR, unexpected layouts):
   rosbags' (or mcap_ros2's) per-message deserializer.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import sqlite3
import tempfile
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.ingest.sources import layout, mcapchunks
from qsls.pipeline.ingest.sources.base import BAG_HINT, TopicInfo, Trajectory, bag_root, detect
from qsls.pipeline.ingest.sources.listing import Rosbag2Listing, open_rosbag2
from qsls.pipeline.ingest.sources.ros1index import Batch, open_ros1, ros1_batches
from qsls.pipeline.ingest.sources.sqlite import sqlite_batches
from qsls.pipeline.ingest.sources.write import ODOMETRY, TF, typestore

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


def normalize_type(name: str) -> str:
    """``pkg/Type`` -> ``pkg/msg/Type`` (ROS2 naming, as rosbags uses)."""
    parts = name.strip("/").split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return "/".join(parts)


def norm_frame(name: str) -> str:
    return name.strip().lstrip("/")


# --------------------------------------------------------------------------- field extraction
def _pose_of(msg: Any, msgtype: str) -> tuple[Any, Any]:
    """(header, geometry_msgs/Pose-like object with position/orientation) of a message."""
    if msgtype == ODOMETRY or msgtype.endswith("PoseWithCovarianceStamped"):
        return msg.header, msg.pose.pose
    if msgtype.endswith("PoseStamped"):
        return msg.header, msg.pose
    raise ValueError(msgtype)


def _stamp(header: Any) -> int:
    st = header.stamp
    return int(st.sec) * 1_000_000_000 + int(getattr(st, "nanosec", getattr(st, "nsec", 0)))


def objects_to_arrays(
    msgs: list[Any], logs: list[int], msgtype: str, truth_frame: str | None, name: str
) -> tuple[
    np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, str, str, np.ndarray | None,
    np.ndarray | None,
]:  # fmt: skip
    """(header_ns, log_ns, pose (n,7), twist (n,6)|None, frame, child, pose covariance
    diagonal (n,6)|None, twist covariance diagonal (n,6)|None) from message objects."""
    rows: list[tuple[float, ...]] = []
    stamps: list[int] = []
    out_logs: list[int] = []
    twists: list[tuple[float, ...]] = []
    variances: list[np.ndarray] = []
    frame = child = ""
    if msgtype == TF or msgtype.endswith("TransformStamped"):
        if msgtype == TF:
            if not truth_frame:
                raise InputError(tf_frames_message(name, msgs))
            parent, want = (norm_frame(x) for x in truth_frame.strip().lstrip("/").split("/", 1))
        for msg, log in zip(msgs, logs, strict=True):
            transforms = msg.transforms if msgtype == TF else [msg]
            for tr in transforms:
                if msgtype == TF and (
                    norm_frame(tr.header.frame_id) != parent
                    or norm_frame(tr.child_frame_id) != want
                ):
                    continue
                t, r = tr.transform.translation, tr.transform.rotation
                rows.append((t.x, t.y, t.z, r.x, r.y, r.z, r.w))
                stamps.append(_stamp(tr.header))
                out_logs.append(log)
                frame, child = tr.header.frame_id, tr.child_frame_id
        if msgtype == TF and not rows:
            raise InputError(tf_frames_message(name, msgs, truth_frame))
    else:
        for msg, log in zip(msgs, logs, strict=True):
            header, pose = _pose_of(msg, msgtype)
            p, q = pose.position, pose.orientation
            rows.append((p.x, p.y, p.z, q.x, q.y, q.z, q.w))
            stamps.append(_stamp(header))
            out_logs.append(log)
            if msgtype == ODOMETRY:
                lin, ang = msg.twist.twist.linear, msg.twist.twist.angular
                twists.append((lin.x, lin.y, lin.z, ang.x, ang.y, ang.z))
                cov = (np.asarray(msg.pose.covariance), np.asarray(msg.twist.covariance))
                variances.append(np.concatenate([c.reshape(6, 6).diagonal() for c in cov]))
        if msgs:
            frame = msgs[0].header.frame_id
            child = getattr(msgs[0], "child_frame_id", "")
    pose = np.array(rows, dtype=float).reshape(-1, 7)
    twist = np.array(twists, dtype=float).reshape(-1, 6) if msgtype == ODOMETRY else None
    var = np.array(variances, dtype=float).reshape(-1, 12) if msgtype == ODOMETRY else None
    return (
        np.array(stamps, dtype=np.int64),
        np.array(out_logs, dtype=np.int64),
        pose,
        twist,
        frame,
        child,
        None if var is None else var[:, :6],
        None if var is None else var[:, 6:],
    )


def tf_frames_message(name: str, msgs: list[Any], asked: str | None = None) -> str:
    counts: dict[str, int] = {}
    for msg in msgs:
        for tr in msg.transforms:
            key = f"{norm_frame(tr.header.frame_id)}/{norm_frame(tr.child_frame_id)}"
            counts[key] = counts.get(key, 0) + 1
    pairs = ", ".join(f"{k} ({v})" for k, v in sorted(counts.items())) or "none"
    head = (
        f"topic {name} has no transform {asked}"
        if asked
        else f"topic {name} is a tf2_msgs/msg/TFMessage topic"
    )
    return f"{head}; pass --truth-frame PARENT/CHILD, one of: {pairs}"


def _trajectory(
    name: str,
    msgtype: str,
    header_ns: np.ndarray,
    log_ns: np.ndarray,
    pose: np.ndarray,
    twist: np.ndarray | None,
    frame: str,
    child: str,
    decoder: str,
    pose_var: np.ndarray | None = None,
    twist_var: np.ndarray | None = None,
) -> Trajectory:
    known = [v for v in (pose_var, twist_var) if v is not None]
    recorded = any(np.any(v != 0) for v in known)  # all zero: unknown (ROS convention)
    return Trajectory(
        name=name,
        msgtype=msgtype,
        # contiguous: a column of ROS1's index would keep the whole index alive
        header_ns=np.ascontiguousarray(header_ns, dtype=np.int64),
        log_ns=np.ascontiguousarray(log_ns, dtype=np.int64),
        position=np.ascontiguousarray(pose[:, :3], dtype=float),
        orientation=np.ascontiguousarray(pose[:, 3:7], dtype=float),
        velocity=None if twist is None else np.ascontiguousarray(twist[:, :3], dtype=float),
        frame_id=frame,
        child_frame_id=child,
        decoder=decoder,
        pose_var=_variances(pose_var, len(header_ns)) if recorded else None,
        twist_var=_variances(twist_var, len(header_ns)) if recorded else None,
    )


def _variances(v: np.ndarray | None, n: int) -> np.ndarray:
    """A covariance diagonal ``(n, 6)``; zeros where the message had none."""
    return np.zeros((n, 6)) if v is None else np.ascontiguousarray(v, dtype=float)


class _Columns:
    """One topic's fields, filled batch by batch into arrays allocated once (for the count
    the bag's index or statistics give; doubled if more arrive): the read holds the
    topic's fields and one batch, never a list of batches to concatenate. The covariance
    diagonals are allocated at their first non-zero value (zeros before it)."""

    WIDTH: ClassVar[dict[str, int]] = {"header_ns": 0, "log_ns": 0, "position": 3, "orientation": 4, "velocity": 3,
             "pose_var": 6, "twist_var": 6}  # fmt: skip

    def __init__(self, count: int, twist: bool) -> None:
        cap = max(int(count), 16)
        self.n = 0
        self.cols: dict[str, np.ndarray] = {
            k: np.empty((cap, w) if w else cap, np.int64 if not w else float)
            for k, w in self.WIDTH.items()
            if k not in ("pose_var", "twist_var") and (twist or k != "velocity")
        }

    def add(self, d: layout.Decoded, logs: np.ndarray) -> None:
        m = len(logs)
        a, b = self.n, self.n + m
        cap = len(self.cols["log_ns"])
        if b > cap:
            for k, old in self.cols.items():
                grown = np.zeros((max(b, 2 * cap), *old.shape[1:]), old.dtype)
                grown[:a] = old[:a]
                self.cols[k] = grown
            cap = len(self.cols["log_ns"])
        c = self.cols
        c["header_ns"][a:b] = d.header_ns
        c["log_ns"][a:b] = logs
        c["position"][a:b] = d.pose[:, :3]
        c["orientation"][a:b] = d.pose[:, 3:7]
        if "velocity" in c and d.twist is not None:
            c["velocity"][a:b] = d.twist[:, :3]
        for k in ("pose_var", "twist_var"):
            v = getattr(d, k)
            if v is None or (k not in c and not np.any(v != 0)):
                continue
            if k not in c:  # the first covariance recorded: zeros before it
                c["pose_var"], c["twist_var"] = np.zeros((cap, 6)), np.zeros((cap, 6))
            c[k][a:b] = v
        self.n = b

    def trajectory(self, info: TopicInfo, frame: str, child: str) -> Trajectory:
        """The topic in log-time order (stable: batches come in chunk order)."""
        n = self.n
        cols, self.cols = self.cols, {}
        for k, v in cols.items():  # allocated for more: keep only what was read
            cols[k] = v if len(v) == n else v[:n].copy()
        if np.any(cols["log_ns"][1:] < cols["log_ns"][:-1]):
            order = np.argsort(cols["log_ns"], kind="stable")
            for k in cols:  # one array at a time: one copy alive at once
                cols[k] = cols[k][order]
        return Trajectory(
            name=info.topic,
            msgtype=info.msgtype,
            header_ns=cols["header_ns"],
            log_ns=cols["log_ns"],
            position=cols["position"],
            orientation=cols["orientation"],
            velocity=cols.get("velocity"),
            frame_id=frame,
            child_frame_id=child,
            decoder="numpy",
            pose_var=cols.get("pose_var"),
            twist_var=cols.get("twist_var"),
        )


# --------------------------------------------------------------------------- sources
class BagSource:
    """An open bag (ROS1, rosbag2 folder or file, plain MCAP)."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.kind = detect(self.path)
        if self.kind in ("tum", "euroc"):
            raise InputError(
                f"{self.path}: a text trajectory, not a bag; pass it with --vio/--truth"
            )
        self._tmp: str | None = None
        self._reader: Any = None
        self._listed: Rosbag2Listing | None = None  # from metadata.yaml (listing.py)
        self._ros1: Any = None  # rosbags' ROS1 reader with a numpy index (ros1index.open_ros1)
        self._mcap: Any = None
        self._fh: Any = None
        try:
            self._open()
        except InputError:
            self.close()
            raise
        except Exception as exc:
            self.close()
            msg = " ".join(str(exc).split()) or exc.__class__.__name__
            hint = locked_hint(exc) or damaged_hint(self.kind)
            raise InputError(f"{self.path}: cannot read the bag ({msg}); {hint}") from None

    # ---- opening
    def _open(self) -> None:
        if self.kind == "mcap":
            from mcap.reader import make_reader

            self._fh = open(self.path, "rb")  # noqa: SIM115 (closed in close())
            self._mcap = make_reader(self._fh, validate_crcs=True)
            summary = self._mcap.get_summary()
            if summary is None:
                raise InputError(
                    f"{self.path}: MCAP file without a summary section; {damaged_hint(self.kind)}"
                )
            self._summary = summary
            return
        if self.kind == "rosbag2":
            self._listed = open_rosbag2(bag_root(self.path))
            if self._listed is not None:
                return  # rosbags' reader only when it is needed (_rosbags)
        if self.kind == "ros1":
            self._ros1 = open_ros1(self._ros1_path())
            return  # AnyReader (typestore, index as objects) only when it is needed
        self._open_rosbags()

    def _ros1_path(self) -> Path:
        """The ROS1 bag under a ``.bag`` name (rosbags' readers go by the suffix)."""
        if self.path.suffix == ".bag":
            return self.path
        if self._tmp is None:
            return self._link(self.path, self.path.name + ".bag")
        return Path(self._tmp) / (self.path.name + ".bag")

    def _open_rosbags(self) -> Any:
        from rosbags.highlevel import AnyReader

        target = self.path
        if self.kind == "ros1":
            target = self._ros1_path()
        elif self.kind == "rosbag2":
            target = bag_root(self.path)
        elif self.kind == "db3":
            target = self._db3_folder(self.path)
        self._reader = AnyReader([target], default_typestore=typestore(ros1=False))
        self._reader.open()
        return self._reader

    def _rosbags(self) -> Any:
        """rosbags' reader of a bag that is not a plain MCAP, opened on first use."""
        return self._reader if self._reader is not None else self._open_rosbags()

    @property
    def _cdr(self) -> bool:
        """Messages are CDR (ROS 2, MCAP), not ROS1."""
        if self._mcap is not None or self._listed is not None:
            return True
        return self._ros1 is None and self._reader.is2

    def _link(self, src: Path, name: str) -> Path:
        self._tmp = tempfile.mkdtemp(prefix="qsls-bag-")
        dst = Path(self._tmp) / name
        os.symlink(src.resolve(), dst)
        return dst

    def _db3_folder(self, db: Path) -> Path:
        """A rosbag2 folder for a lone ``.db3``: a link to it and metadata from its tables."""
        import yaml

        try:
            con = sqlite3.connect(f"file:{db.resolve()}?mode=ro", uri=True)
            try:
                topics = con.execute(
                    "SELECT id, name, type, serialization_format FROM topics"
                ).fetchall()
                stats = {
                    r[0]: r[1:]
                    for r in con.execute(
                        "SELECT topic_id, COUNT(*), MIN(timestamp), MAX(timestamp) "
                        "FROM messages GROUP BY topic_id"
                    )
                }
            finally:
                con.close()
        except sqlite3.Error as exc:
            if hint := locked_hint(exc):
                raise InputError(f"{db}: {hint}") from None
            raise InputError(
                f"{db}: not a readable rosbag2 sqlite3 file ({exc}); {BAG_HINT}"
            ) from None
        folder = self._link(db, db.name).parent
        starts = [s[1] for s in stats.values()] or [0]
        stops = [s[2] for s in stats.values()] or [0]
        meta = {
            "rosbag2_bagfile_information": {
                "version": 5,
                "storage_identifier": "sqlite3",
                "relative_file_paths": [db.name],
                "duration": {"nanoseconds": int(max(stops) - min(starts))},
                "starting_time": {"nanoseconds_since_epoch": int(min(starts))},
                "message_count": int(sum(s[0] for s in stats.values())),
                "topics_with_message_count": [
                    {
                        "topic_metadata": {
                            "name": name,
                            "type": typ,
                            "serialization_format": fmt,
                            "offered_qos_profiles": "",
                        },
                        "message_count": int(stats.get(tid, (0,))[0]),
                    }
                    for tid, name, typ, fmt in topics
                ],
                "compression_format": "",
                "compression_mode": "",
            }
        }
        (folder / "metadata.yaml").write_text(yaml.safe_dump(meta))
        return folder

    def close(self) -> None:
        if self._ros1 is not None:
            with contextlib.suppress(Exception):
                self._ros1.close()
            self._ros1 = None
        if self._reader is not None:
            with contextlib.suppress(Exception):
                self._reader.close()
            self._reader = None
        if self._fh is not None:
            self._fh.close()
            self._fh = None
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None

    def __enter__(self) -> BagSource:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # ---- topics
    def topics(self) -> list[TopicInfo]:
        out: dict[str, TopicInfo] = {}
        if self._mcap is not None:
            s = self._summary
            counts = s.statistics.channel_message_counts if s.statistics else {}
            for cid, ch in s.channels.items():
                schema = s.schemas.get(ch.schema_id)
                mt = normalize_type(schema.name) if schema else "?"
                prev = out.get(ch.topic)
                n = int(counts.get(cid, 0)) + (prev.count if prev else 0)
                out[ch.topic] = TopicInfo(ch.topic, mt, n, self.path)
        elif self._listed is not None:
            for topic, (mt, n) in self._listed.topics.items():
                out[topic] = TopicInfo(topic, mt, n, self.path)
        elif self._ros1 is not None:
            for topic, info in self._ros1.topics.items():
                out[topic] = TopicInfo(topic, info.msgtype or "?", int(info.msgcount), self.path)
        else:
            for topic, info in self._reader.topics.items():
                out[topic] = TopicInfo(topic, info.msgtype or "?", int(info.msgcount), self.path)
        return [out[k] for k in sorted(out)]

    # ---- reading
    def read(
        self,
        topic: str,
        *,
        truth_frame: str | None = None,
        fast: bool = True,
        progress: Progress = NULL_PROGRESS,
    ) -> Trajectory:
        """One topic as a :class:`Trajectory` (``truth_frame`` picks a TF transform)."""
        return self.read_many([(topic, truth_frame)], fast=fast, progress=progress)[0]

    def read_many(
        self,
        requests: list[tuple[str, str | None]],
        *,
        fast: bool = True,
        progress: Progress = NULL_PROGRESS,
    ) -> list[Trajectory]:
        """Several topics in one pass over the bag: ``[(topic, truth_frame or None), ...]``."""
        known = {t.topic: t for t in self.topics()}
        infos = []
        for topic, _ in requests:
            if topic not in known:
                raise InputError(f"{self.path}: no topic {topic}")
            infos.append(known[topic])
        names = ", ".join(dict.fromkeys(i.topic for i in infos))
        progress.start(f"reading {names}", total=sum(i.count for i in infos) or None)
        try:
            found: dict[str, Trajectory] = {}
            if fast:
                fixed = [i for i in infos if i.msgtype in layout.FIXED_TYPES]
                found = self._indexed_fast(list({i.topic: i for i in fixed}.values()), progress)
            rest = list({i.topic: i for i in infos if i.topic not in found}.values())
            raws = self._raw_pass(rest, progress) if rest else {}
            for info in rest:
                self._check_count(info, len(raws[info.topic][0]))
            return [
                found[t] if t in found else self._decode(known[t], raws[t], frame, fast)
                for t, frame in requests
            ]
        except (InputError, layout.LayoutError):
            raise
        except Exception as exc:
            msg = " ".join(str(exc).split()) or exc.__class__.__name__
            hint = locked_hint(exc) or self._type_hint(exc, infos) or damaged_hint(self.kind)
            raise InputError(f"{self.path}: error while reading {names} ({msg}); {hint}") from None
        finally:
            progress.finish()

    def _type_hint(self, exc: BaseException, infos: list[TopicInfo]) -> str | None:
        """When the messages do not decode as the type the bag lists (a ``metadata.yaml``
        naming the wrong type), say so: the bag need not be damaged."""
        from rosbags.highlevel.anyreader import AnyReaderError
        from rosbags.serde import SerdeError

        mismatch = "size mismatch" in str(exc) or isinstance(exc, SerdeError)
        # a type the bag's own definitions do not hold: rosbags' typestore lookup fails
        unknown = isinstance(exc, KeyError) and str(exc.args[0] if exc.args else "") in {
            i.msgtype for i in infos
        }
        if not (unknown or (isinstance(exc, SerdeError | AnyReaderError) and mismatch)):
            return None
        listed = ", ".join(f"{i.topic} as {i.msgtype}" for i in infos)
        where = "its metadata.yaml" if self._listed is not None else "the bag"
        return (
            f"the messages do not decode as the types {where} lists ({listed}); check those "
            f"types (a hand-edited metadata.yaml?), else {damaged_hint(self.kind)}"
        )

    def _check_count(self, info: TopicInfo, n: int) -> None:
        """Refuse a topic read with fewer (or more) messages than the bag's own index or
        statistics list: a damaged record silently ends the per-message readers' chunk."""
        if info.count > 0 and n != info.count:
            raise InputError(
                f"{self.path}: topic {info.topic}: {n} messages read where the bag's index "
                f"lists {info.count} (a damaged record ends the rest of its chunk); "
                f"{damaged_hint(self.kind)}"
            )

    def _indexed_fast(self, infos: list[TopicInfo], progress: Progress) -> dict[str, Trajectory]:
        """Fixed-layout topics through the bag's own index: ROS1 (:mod:`ros1index`), sqlite3
        (:mod:`sqlite`) or MCAP chunks, plain or rosbag2 (:mod:`mcapchunks`); an empty dict:
        fall back to the raw pass, which still decodes them at once where their layout fits
        (an MCAP file without a usable index raises the same ``LayoutError`` as a misfit)."""
        if not infos:
            return {}
        if self._ros1 is not None:
            r1 = self._ros1
            ids = {i.topic: {c.id for c in r1.connections if c.topic == i.topic} for i in infos}
            conns = set().union(*ids.values())
            return self._batches_fast(infos, ids, lambda: ros1_batches(r1, conns), progress)
        dbs = self._sqlite_files() if self._mcap is None else None
        if dbs:
            topics = [i.topic for i in infos]
            ids = {t: {k} for k, t in enumerate(topics)}
            types = [i.msgtype for i in infos]
            return self._batches_fast(
                infos, ids, lambda: sqlite_batches(dbs, topics, types), progress
            )
        files = self._mcap_files()
        if not files:
            return {}
        ids = {info.topic: {k} for k, info in enumerate(infos)}
        return self._batches_fast(infos, ids, lambda: self._mcap_batches(files, infos), progress)

    def _mcap_files(self) -> list[Path] | None:
        """The MCAP files of a plain MCAP or an MCAP rosbag2 without message/file
        compression (chunk compression is fine); None for anything else."""
        if self._mcap is not None:
            return [self.path]
        if self._listed is not None:
            return self._listed.files if self._listed.storage == "mcap" else None
        from rosbags.rosbag2.storage_mcap import McapReader

        return self._storage_files(McapReader)

    def _mcap_batches(self, files: list[Path], infos: list[TopicInfo]) -> Iterator[Batch]:
        """The messages of ``infos`` in every MCAP file, labelled by their index in ``infos``;
        ``LayoutError`` when a channel is not CDR of the topic's type."""
        label = {info.topic: k for k, info in enumerate(infos)}
        for f in files:
            summary = self._summary if self._mcap is not None else mcapchunks.read_summary(f)
            wanted = {}
            for cid, ch in summary.channels.items():
                if ch.topic not in label:
                    continue
                schema = summary.schemas.get(ch.schema_id)
                mt = normalize_type(schema.name) if schema else "?"
                if ch.message_encoding != "cdr" or mt != infos[label[ch.topic]].msgtype:
                    raise layout.LayoutError(f"channel {ch.topic} is not cdr {mt}")
                wanted[cid] = label[ch.topic]
            yield from mcapchunks.mcap_batches(f, summary, wanted)

    def _batches_fast(
        self,
        infos: list[TopicInfo],
        ids: dict[str, set[int]],
        batches: Callable[[], Iterable[Batch]],
        progress: Progress,
    ) -> dict[str, Trajectory]:
        """Decode ``batches`` (``Batch.conn`` in ``ids[topic]``) per topic, in log-time order
        (stable: batches come in chunk order); an empty dict on a ``LayoutError``."""
        encoding = "cdr" if self._cdr else "ros1"
        cols = {i.topic: _Columns(i.count, i.msgtype == ODOMETRY) for i in infos}
        # (log time, frame_id, child_frame_id) of each topic's first message in log-time order
        # (the per-message path's): chunks need not be in time order
        first: dict[str, tuple[int, str, str]] = {}
        try:
            for batch in batches():
                for info in infos:
                    m = np.isin(batch.conn, list(ids[info.topic]))
                    if not m.any():
                        continue
                    if m.all():  # a batch of one topic (sqlite3): no copies
                        starts, ends, logs = batch.starts, batch.ends, batch.log_ns
                    else:
                        starts, ends, logs = batch.starts[m], batch.ends[m], batch.log_ns[m]
                    d = layout.decode(
                        batch.buf, starts, ends, info.msgtype, encoding, trimmed=batch.trimmed
                    )
                    cols[info.topic].add(d, logs)
                    k = int(np.argmin(logs))
                    if info.topic not in first or logs[k] < first[info.topic][0]:
                        if k:
                            one = slice(k, k + 1)
                            d = layout.decode(
                                batch.buf, starts[one], ends[one], info.msgtype, encoding,
                                trimmed=batch.trimmed,
                            )  # fmt: skip
                        first[info.topic] = (int(logs[k]), d.frame_id, d.child_frame_id)
                    del d
                progress.advance(len(batch.starts))
                del batch  # a memory-mapped window is unmapped before the next is mapped
        except layout.LayoutError:
            return {}
        return {
            i.topic: cols[i.topic].trajectory(i, first[i.topic][1], first[i.topic][2])
            for i in infos
            if i.topic in first
        }

    def _raw_pass(self, infos: list[TopicInfo], progress: Progress) -> dict[str, tuple]:
        """``{topic: (raw messages, log stamps, schema)}`` in one pass over the bag."""
        out: dict[str, tuple[list[bytes], list[int], Any]] = {
            i.topic: ([], [], None) for i in infos
        }
        n = 0
        if self._mcap is not None:
            for schema, channel, message in self._mcap.iter_messages(topics=list(out)):
                if channel.message_encoding != "cdr":
                    raise InputError(
                        f"{self.path}: topic {channel.topic} is encoded as "
                        f"{channel.message_encoding!r}; qsls reads ROS2 messages (cdr encoding)"
                    )
                raws, logs, _ = out[channel.topic]
                if out[channel.topic][2] is None:
                    out[channel.topic] = (raws, logs, schema)
                raws.append(bytes(message.data))
                logs.append(int(message.log_time))
                n += 1
                if n % 4096 == 0:
                    progress.advance(4096)
        elif (dbs := self._sqlite_files()) is not None:
            topics = list(out)
            for batch in sqlite_batches(dbs, topics):  # one topic and file each, in row order
                raws, logs, _ = out[topics[int(batch.conn[0])]]
                order = np.argsort(batch.log_ns, kind="stable")  # by log time, as rosbags
                buf = batch.buf.tobytes()
                raws.extend(buf[batch.starts[i] : batch.ends[i]] for i in order)
                logs.extend(batch.log_ns[order].tolist())
                n += len(order)
        else:
            r = self._rosbags()
            conns = [c for c in r.connections if c.topic in out]
            for c, log, raw in r.messages(connections=conns):
                raws, logs, _ = out[c.topic]
                raws.append(raw)
                logs.append(log)
                n += 1
                if n % 4096 == 0:
                    progress.advance(4096)
        progress.advance(n % 4096)
        return out

    def _sqlite_files(self) -> list[Path] | None:
        """The ``.db3`` files of an uncompressed sqlite3 rosbag2, read directly with one query
        per topic (rosbags' reader yields one message at a time); None for anything else."""
        if self._listed is not None:
            return self._listed.files if self._listed.storage == "sqlite3" else None
        from rosbags.rosbag2.storage_sqlite3 import Sqlite3Reader

        return self._storage_files(Sqlite3Reader)

    def _storage_files(self, storage: type[Any]) -> list[Path] | None:
        """The files of a rosbag2 without message/file compression whose storages are all
        ``storage`` (rosbags' reader class); None for anything else."""
        if self._reader is None or not self._reader.is2:
            return None
        files = []
        for bag in self._reader.readers:
            storages = getattr(bag.storage, "storages", [bag.storage])  # a folder, or one file
            if bag.compression_mode or not all(
                isinstance(s, storage) and isinstance(s.path, Path) for s in storages
            ):
                return None
            files += [s.path for s in storages]
        return files

    def _decode(
        self, info: TopicInfo, raw: tuple, truth_frame: str | None, fast: bool
    ) -> Trajectory:
        raws, logs, schema = raw
        mt = info.msgtype
        cdr = self._cdr
        if fast and mt in layout.FIXED_TYPES:
            try:
                buf, starts, ends = layout.concat(raws)
                d = layout.decode(buf, starts, ends, mt, "cdr" if cdr else "ros1")
                return _trajectory(
                    info.topic, mt, d.header_ns, np.array(logs, np.int64), d.pose, d.twist,
                    d.frame_id, d.child_frame_id, "numpy", d.pose_var, d.twist_var,
                )  # fmt: skip
            except layout.LayoutError:
                pass  # the deserializer below
        if self._mcap is not None:
            msgs: list[Any] = []
            if raws:
                from mcap_ros2.decoder import DecoderFactory

                dec = DecoderFactory().decoder_for("cdr", schema)
                if dec is None:
                    raise InputError(f"{self.path}: cannot decode topic {info.topic} ({mt})")
                msgs = [dec(x) for x in raws]
        else:
            reader = self._rosbags()
            msgs = [reader.deserialize(x, mt) for x in raws]
        h, lg, pose, twist, frame, child, pv, tv = objects_to_arrays(
            msgs, logs, mt, truth_frame, info.topic
        )
        return _trajectory(info.topic, mt, h, lg, pose, twist, frame, child, "deserializer", pv, tv)
