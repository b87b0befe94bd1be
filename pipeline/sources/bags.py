"""Read one pose topic of a bag into a :class:`Trajectory`.

Bags are opened with rosbags (``AnyReader``: ROS1 ``.bag`` and rosbag2 folders with
sqlite3 or MCAP storage) and plain MCAP files with the ``mcap`` package; bag formats are
never parsed by hand, with one exception, the ROS1 fast path below.

Decoding, fastest first:

1. ROS1, fixed-layout types (:mod:`qsls.pipeline.sources.layout`): rosbags' own index
   (``Reader.indexes``: time, chunk position and offset of every message, ``Reader.chunks``:
   where each chunk's data starts and how it is compressed) gives every message record's
   place. Uncompressed chunks are memory-mapped, so only the pages holding the wanted
   records are read (camera images in the same chunks are skipped); compressed chunks
   that hold wanted messages are decompressed once each. The record headers are checked
   (op code, connection id and time equal what the index says) and the message data
   decoded for the whole topic at once. A test checks the sliced bytes against rosbags'
   ``messages()`` byte for byte.
2. ROS2 and MCAP, fixed-layout types: raw messages from the reader, decoded at once.
3. Anything else (``tf2_msgs/msg/TFMessage``, big-endian CDR, unexpected layouts):
   rosbags' (or mcap_ros2's) per-message deserializer.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import sqlite3
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.errors import InputError
from qsls.pipeline.progress import NULL_PROGRESS, Progress
from qsls.pipeline.sources import layout
from qsls.pipeline.sources.base import BAG_HINT, TopicInfo, Trajectory, bag_root, detect
from qsls.pipeline.sources.write import ODOMETRY, TF, typestore

_DAMAGED = (
    "it looks truncated or damaged; if the recording was cut off, repair it "
    "('rosbag reindex' for ROS1, 'ros2 bag reindex' for rosbag2) and try again"
)


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
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, str, str]:
    """(header_ns, log_ns, pose (n,7), twist (n,6)|None, frame, child) from message objects."""
    rows: list[tuple[float, ...]] = []
    stamps: list[int] = []
    out_logs: list[int] = []
    twists: list[tuple[float, ...]] = []
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
        if msgs:
            frame = msgs[0].header.frame_id
            child = getattr(msgs[0], "child_frame_id", "")
    pose = np.array(rows, dtype=float).reshape(-1, 7)
    twist = np.array(twists, dtype=float).reshape(-1, 6) if msgtype == ODOMETRY else None
    return (
        np.array(stamps, dtype=np.int64),
        np.array(out_logs, dtype=np.int64),
        pose,
        twist,
        frame,
        child,
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
) -> Trajectory:
    return Trajectory(
        name=name,
        msgtype=msgtype,
        header_ns=np.asarray(header_ns, dtype=np.int64),
        log_ns=np.asarray(log_ns, dtype=np.int64),
        position=np.ascontiguousarray(pose[:, :3], dtype=float),
        orientation=np.ascontiguousarray(pose[:, 3:7], dtype=float),
        velocity=None if twist is None else np.ascontiguousarray(twist[:, :3], dtype=float),
        frame_id=frame,
        child_frame_id=child,
        decoder=decoder,
    )


# --------------------------------------------------------------------------- ROS1 fast path
def ros1_slices(
    reader1: Any, conn_ids: set[int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Locate the data of every message of ``conn_ids`` from rosbags' ROS1 index.

    Returns ``(buf, starts, ends, log_ns)`` in index (time) order: message ``i`` is
    ``buf[starts[i]:ends[i]]``. Raises :class:`layout.LayoutError` when a record is not
    where the index says (the caller then uses rosbags' reader).
    """
    from rosbags.rosbag1.reader import decompressors

    parts = [np.array(reader1.indexes[c], dtype=np.int64).reshape(-1, 3) for c in sorted(conn_ids)]
    idx = np.concatenate(parts) if parts else np.zeros((0, 3), np.int64)
    order = np.lexsort((idx[:, 2], idx[:, 1], idx[:, 0]))
    idx = idx[order]
    times, chunk_pos, offsets = idx[:, 0], idx[:, 1], idx[:, 2]
    if len(idx) == 0:
        return np.zeros(0, np.uint8), np.zeros(0, np.int64), np.zeros(0, np.int64), times
    chunks = reader1.chunks
    uniq = np.unique(chunk_pos)
    plain = all(chunks[int(c)].decompressor is decompressors["none"] for c in uniq)
    if plain:
        buf = np.memmap(reader1.path, dtype=np.uint8, mode="r")
        base = {int(c): chunks[int(c)].datapos for c in uniq}
    else:
        blobs = []
        base = {}
        at = 0
        with open(reader1.path, "rb") as fh:
            for c in uniq.tolist():
                ch = chunks[c]
                fh.seek(ch.datapos)
                raw = ch.decompressor(fh.read(ch.datasize))
                blobs.append(raw)
                base[c] = at
                at += len(raw)
        buf = np.frombuffer(b"".join(blobs), dtype=np.uint8)
    bases = np.array([base[c] for c in uniq.tolist()], dtype=np.int64)
    rec = bases[np.searchsorted(uniq, chunk_pos)] + offsets
    # record: uint32 header_len, header fields (uint32 len, "name=value"), uint32 data_len, data
    hlen = layout._u32(buf, rec)
    if np.any(hlen != hlen[0]):
        raise layout.LayoutError("record headers of different lengths")
    h0 = int(hlen[0])
    fields = _header_fields(bytes(buf[int(rec[0]) + 4 : int(rec[0]) + 4 + h0]))
    if not {"op", "conn", "time"} <= set(fields):
        raise layout.LayoutError("record header without op/conn/time")
    op_at, conn_at, time_at = (fields[k] for k in ("op", "conn", "time"))
    if not np.all(buf[rec + 4 + op_at] == 2):
        raise layout.LayoutError("index points at a record that is not message data")
    conns = layout._u32(buf, rec + 4 + conn_at)
    if not np.all(np.isin(conns, list(conn_ids))):
        raise layout.LayoutError("record of another connection")
    t = layout._gather(buf, rec + 4 + time_at, 8).view("<u4")
    if not np.array_equal(t[:, 0].astype(np.int64) * 1_000_000_000 + t[:, 1], times):
        raise layout.LayoutError("record time differs from the index")
    dlen = layout._u32(buf, rec + 4 + h0)
    starts = rec + 8 + h0
    ends = starts + dlen
    if ends.max() > len(buf):
        raise layout.LayoutError("message data beyond the chunk")
    return buf, starts, ends, times


def _header_fields(raw: bytes) -> dict[str, int]:
    """Offsets (within the header) of each field's value."""
    out = {}
    i = 0
    while i + 4 <= len(raw):
        n = int.from_bytes(raw[i : i + 4], "little")
        field = raw[i + 4 : i + 4 + n]
        name, _, _ = field.partition(b"=")
        out[name.decode(errors="replace")] = i + 4 + len(name) + 1
        i += 4 + n
    return out


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
            raise InputError(f"{self.path}: cannot read the bag ({msg}); {_DAMAGED}") from None

    # ---- opening
    def _open(self) -> None:
        if self.kind == "mcap":
            from mcap.reader import make_reader

            self._fh = open(self.path, "rb")  # noqa: SIM115 (closed in close())
            self._mcap = make_reader(self._fh)
            summary = self._mcap.get_summary()
            if summary is None:
                raise InputError(f"{self.path}: MCAP file without a summary section; {_DAMAGED}")
            self._summary = summary
            return
        from rosbags.highlevel import AnyReader

        target = self.path
        if self.kind == "ros1" and self.path.suffix != ".bag":
            target = self._link(self.path, self.path.name + ".bag")
        elif self.kind == "rosbag2":
            target = bag_root(self.path)
        elif self.kind == "db3":
            target = self._db3_folder(self.path)
        self._reader = AnyReader([target], default_typestore=typestore(ros1=False))
        self._reader.open()

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
        info = {t.topic: t for t in self.topics()}.get(topic)
        if info is None:
            raise InputError(f"{self.path}: no topic {topic}")
        progress.start(f"reading {topic}", total=info.count or None)
        try:
            if self._mcap is not None:
                return self._read_mcap(info, truth_frame, fast, progress)
            return self._read_rosbags(info, truth_frame, fast, progress)
        except (InputError, layout.LayoutError):
            raise
        except Exception as exc:
            msg = " ".join(str(exc).split()) or exc.__class__.__name__
            raise InputError(
                f"{self.path}: error while reading {topic} ({msg}); {_DAMAGED}"
            ) from None
        finally:
            progress.finish()

    def _read_rosbags(
        self, info: TopicInfo, truth_frame: str | None, fast: bool, progress: Progress
    ) -> Trajectory:
        r = self._reader
        conns = [c for c in r.connections if c.topic == info.topic]
        mt = info.msgtype
        if fast and mt in layout.FIXED_TYPES and not r.is2:
            try:
                buf, starts, ends, logs = ros1_slices(r.readers[0], {c.id for c in conns})
                d = layout.decode(buf, starts, ends, mt, "ros1")
                progress.advance(len(starts))
                return _trajectory(
                    info.topic, mt, d.header_ns, logs, d.pose, d.twist, d.frame_id,
                    d.child_frame_id, "numpy",
                )  # fmt: skip
            except layout.LayoutError:
                pass  # fall back to rosbags' reader below
        raws: list[bytes] = []
        logs_l: list[int] = []
        for i, (_c, log, raw) in enumerate(r.messages(connections=conns)):
            raws.append(raw)
            logs_l.append(log)
            if i % 4096 == 4095:
                progress.advance(4096)
        progress.advance(len(raws) % 4096)
        if fast and mt in layout.FIXED_TYPES:
            try:
                buf, starts, ends = layout.concat(raws)
                d = layout.decode(buf, starts, ends, mt, "cdr" if r.is2 else "ros1")
                return _trajectory(
                    info.topic, mt, d.header_ns, np.array(logs_l, np.int64), d.pose, d.twist,
                    d.frame_id, d.child_frame_id, "numpy",
                )  # fmt: skip
            except layout.LayoutError:
                pass
        msgs = [r.deserialize(raw, mt) for raw in raws]
        arrays = objects_to_arrays(msgs, logs_l, mt, truth_frame, info.topic)
        return _trajectory(info.topic, mt, *arrays, "deserializer")

    def _read_mcap(
        self, info: TopicInfo, truth_frame: str | None, fast: bool, progress: Progress
    ) -> Trajectory:
        raws: list[bytes] = []
        logs: list[int] = []
        schema = channel = None
        for i, (schema, channel, message) in enumerate(  # noqa: B007
            self._mcap.iter_messages(topics=[info.topic])
        ):
            raws.append(bytes(message.data))
            logs.append(int(message.log_time))
            if i % 4096 == 4095:
                progress.advance(4096)
        progress.advance(len(raws) % 4096)
        mt = info.msgtype
        if channel is not None and channel.message_encoding != "cdr":
            raise InputError(
                f"{self.path}: topic {info.topic} is encoded as {channel.message_encoding!r}; "
                "qsls reads ROS2 messages (cdr encoding)"
            )
        if fast and mt in layout.FIXED_TYPES:
            try:
                buf, starts, ends = layout.concat(raws)
                d = layout.decode(buf, starts, ends, mt, "cdr")
                return _trajectory(
                    info.topic, mt, d.header_ns, np.array(logs, np.int64), d.pose, d.twist,
                    d.frame_id, d.child_frame_id, "numpy",
                )  # fmt: skip
            except layout.LayoutError:
                pass
        msgs: list[Any] = []
        if raws:
            from mcap_ros2.decoder import DecoderFactory

            dec = DecoderFactory().decoder_for("cdr", schema)
            if dec is None:
                raise InputError(f"{self.path}: cannot decode topic {info.topic} ({mt})")
            msgs = [dec(raw) for raw in raws]
        arrays = objects_to_arrays(msgs, logs, mt, truth_frame, info.topic)
        return _trajectory(info.topic, mt, *arrays, "deserializer")


def iter_topics(paths: list[Path]) -> Iterator[TopicInfo]:
    for p in paths:
        with BagSource(p) as src:
            yield from src.topics()
