"""Read pose topics of a bag into :class:`Trajectory` objects, whatever its format.

Each format has its reader beside its writer, in its own subpackage (:mod:`.ros1`,
:mod:`.rosbag2`, :mod:`.mcap`; text trajectories in :mod:`.text`), behind one protocol
(:class:`~qsls.pipeline.ingest.sources.base.BagReader`: topics, an indexed read, a raw pass,
a per-message deserializer); ``READERS`` maps the kind :func:`detect` finds to its reader.
:class:`BagSource` holds what is the same for every format: the order of the paths below,
decoding at once, the message counts and the errors.

Bags are listed and, off the fast paths, read with rosbags (``AnyReader``: ROS1 ``.bag`` and
rosbag2 folders with sqlite3 or MCAP storage) and plain MCAP files with the ``mcap`` package.
The fast paths below read what those libraries expose (rosbags' ROS1 reader and chunk
list, a rosbag2 folder's ``metadata.yaml``, the sqlite3 tables, MCAP's summary and chunk
indexes) and parse by hand only the record heads they check and the fixed-layout
messages.

Decoding, fastest first:

1. ROS1, fixed-layout types (:mod:`qsls.pipeline.ingest.sources.layout`): the bag's message
   index (time, chunk position and offset of every message, read as numpy arrays from its
   index records, :func:`qsls.pipeline.ingest.sources.ros1.index.open_ros1`) and rosbags'
   ``Reader.chunks`` (where each chunk's data starts and how it is compressed) give every
   message record's place. Uncompressed chunks are memory-mapped, so only the pages holding the wanted
   records are read (camera images in the same chunks are skipped); compressed chunks
   that hold wanted messages are decompressed once each. The record headers are checked
   (op code, connection id and time equal what the index says) and the message data
   decoded for the whole topic at once. A test checks the sliced bytes against rosbags'
   ``messages()`` byte for byte. rosbags' ROS1 reader is opened with its index read by
   numpy (:func:`qsls.pipeline.ingest.sources.ros1.index.open_ros1`); ``AnyReader`` only
   for the per-message path.
2. MCAP (plain, and rosbag2 MCAP storage without message/file compression), fixed-layout
   types (:mod:`qsls.pipeline.ingest.sources.mcap.chunks`): the summary's chunk indexes and
   each chunk's message indexes locate every wanted message; uncompressed chunks are
   memory-mapped, zstd/lz4 chunks decompressed once each with the ``mcap`` package's
   helpers, the records checked against the index and decoded for the whole topic at once.
   A test compares them record for record with the ``mcap`` reader.
3. ROS2 sqlite3 without compression, fixed-layout types (:mod:`qsls.pipeline.ingest.sources.rosbag2.sqlite`):
   the topics from ``metadata.yaml`` (:mod:`qsls.pipeline.ingest.sources.rosbag2.listing`, as for
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

import functools
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.ingest.sources import layout
from qsls.pipeline.ingest.sources.base import (
    METADATA,
    BagReader,
    RawTopic,
    TopicInfo,
    Trajectory,
    damaged_hint,
    detect,
    locked_hint,
)
from qsls.pipeline.ingest.sources.decode import TopicColumns, objects_to_arrays, trajectory_of
from qsls.pipeline.ingest.sources.layout import Batch
from qsls.pipeline.ingest.sources.mcap.reader import McapFileReader
from qsls.pipeline.ingest.sources.msgtypes import ODOMETRY
from qsls.pipeline.ingest.sources.ros1.reader import Ros1Reader
from qsls.pipeline.ingest.sources.rosbag2.reader import Rosbag2Reader

READERS: dict[str, Callable[[Path], BagReader]] = {
    "ros1": Ros1Reader,
    "rosbag2": Rosbag2Reader,
    "db3": functools.partial(Rosbag2Reader, kind="db3"),
    "mcap": McapFileReader,
}
"""The kind :func:`~qsls.pipeline.ingest.sources.base.detect` finds to its format's reader."""


class BagSource:
    """An open bag (ROS1, rosbag2 folder or file, plain MCAP), read through its format's
    :class:`~qsls.pipeline.ingest.sources.base.BagReader`."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.kind = detect(self.path)
        if self.kind not in READERS:
            raise InputError(
                f"{self.path}: a text trajectory, not a bag; pass it with --vio/--truth"
            )
        self.reader: BagReader | None = None
        try:
            self.reader = READERS[self.kind](self.path)
        except InputError:
            raise
        except Exception as exc:
            msg = " ".join(str(exc).split()) or exc.__class__.__name__
            hint = locked_hint(exc) or damaged_hint(self.kind)
            raise InputError(f"{self.path}: cannot read the bag ({msg}); {hint}") from None

    def close(self) -> None:
        if self.reader is not None:
            self.reader.close()
            self.reader = None

    def __enter__(self) -> BagSource:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def _current(self) -> BagReader:
        if self.reader is None:
            raise ValueError(f"{self.path}: the bag is closed")
        return self.reader

    def topics(self) -> list[TopicInfo]:
        """Every topic of the bag, sorted by name."""
        return sorted(self._current().topics(), key=lambda t: t.topic)

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
        return (
            f"the messages do not decode as the types {self._current().listed_by} lists "
            f"({listed}); check those types (a hand-edited {METADATA}?), else "
            f"{damaged_hint(self.kind)}"
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
        """Fixed-layout topics through the bag's own index (the reader's ``indexed``); an
        empty dict: fall back to the raw pass, which still decodes them at once where their
        layout fits (an MCAP file without a usable index raises the same ``LayoutError`` as a
        misfit)."""
        if not infos:
            return {}
        plan = self._current().indexed(infos)
        if plan is None:
            return {}
        ids, batches = plan
        return self._batches_fast(infos, ids, batches, progress)

    def _batches_fast(
        self,
        infos: list[TopicInfo],
        ids: dict[str, set[int]],
        batches: Callable[[], Iterable[Batch]],
        progress: Progress,
    ) -> dict[str, Trajectory]:
        """Decode ``batches`` (``Batch.conn`` in ``ids[topic]``) per topic, in log-time order
        (stable: batches come in chunk order); an empty dict on a ``LayoutError``."""
        encoding = "cdr" if self._current().cdr else "ros1"
        cols = {i.topic: TopicColumns(i.count, i.msgtype == ODOMETRY) for i in infos}
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

    def _raw_pass(self, infos: list[TopicInfo], progress: Progress) -> dict[str, RawTopic]:
        """``{topic: (raw messages, log stamps, schema)}`` in one pass over the bag."""
        return self._current().raw(infos, progress)

    def _decode(
        self, info: TopicInfo, raw: RawTopic, truth_frame: str | None, fast: bool
    ) -> Trajectory:
        raws, logs, schema = raw
        mt = info.msgtype
        reader = self._current()
        if fast and mt in layout.FIXED_TYPES:
            try:
                buf, starts, ends = layout.concat(raws)
                d = layout.decode(buf, starts, ends, mt, "cdr" if reader.cdr else "ros1")
                return trajectory_of(
                    info.topic, mt, d.header_ns, np.array(logs, np.int64), d.pose, d.twist,
                    d.frame_id, d.child_frame_id, "numpy", d.pose_var, d.twist_var,
                )  # fmt: skip
            except layout.LayoutError:
                pass  # the deserializer below
        msgs = reader.deserialize(info, raws, schema)
        h, lg, pose, twist, frame, child, pv, tv = objects_to_arrays(
            msgs, logs, mt, truth_frame, info.topic
        )
        return trajectory_of(
            info.topic, mt, h, lg, pose, twist, frame, child, "deserializer", pv, tv
        )
