"""A rosbag2 bag: a folder with ``metadata.yaml`` (or one of its storage files), or a lone
``.db3`` file.

An uncompressed bag of CDR messages is listed from its ``metadata.yaml`` (:mod:`.listing`)
without opening rosbags' reader; anything else (message or file compression, a lone
``.db3``, a metadata file the listing does not take) opens rosbags' ``AnyReader``, which also
reports what is wrong. The fixed-layout topics of an uncompressed bag are read through its
storage plugin (``STORAGE_PLUGINS``): sqlite3 with SQL (:mod:`.sqlite`), MCAP through the
summary's chunk indexes (:mod:`..mcap.chunks`). docs/ingest.md#formats.
"""

from __future__ import annotations

import contextlib
import shutil
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.core.progress import Progress
from qsls.pipeline.ingest.sources.anyreader import anyreader_raw, open_anyreader
from qsls.pipeline.ingest.sources.base import METADATA, IndexPlan, RawTopic, TopicInfo, bag_root
from qsls.pipeline.ingest.sources.layout import Batch
from qsls.pipeline.ingest.sources.mcap.chunks import topic_batches
from qsls.pipeline.ingest.sources.rosbag2.db3 import db3_folder
from qsls.pipeline.ingest.sources.rosbag2.listing import Rosbag2Listing, open_rosbag2
from qsls.pipeline.ingest.sources.rosbag2.sqlite import sqlite_batches


def _sqlite_plan(files: list[Path], infos: list[TopicInfo]) -> IndexPlan:
    topics = [i.topic for i in infos]
    types = [i.msgtype for i in infos]
    return {t: {k} for k, t in enumerate(topics)}, lambda: sqlite_batches(files, topics, types)


def _mcap_plan(files: list[Path], infos: list[TopicInfo]) -> IndexPlan:
    return {i.topic: {k} for k, i in enumerate(infos)}, lambda: topic_batches(files, infos)


STORAGE_PLUGINS: dict[str, Callable[[list[Path], list[TopicInfo]], IndexPlan]] = {
    "sqlite3": _sqlite_plan,
    "mcap": _mcap_plan,
}
"""A rosbag2 storage (``metadata.yaml``'s ``storage_identifier``) to its indexed read."""


class Rosbag2Reader:
    """An open rosbag2 bag (:class:`~qsls.pipeline.ingest.sources.base.BagReader`);
    ``kind``: ``rosbag2`` (a folder or its storage file) or ``db3`` (a lone ``.db3``)."""

    cdr = True

    def __init__(self, path: Path, kind: str = "rosbag2") -> None:
        self.path, self.kind = Path(path), kind
        self._tmp: Path | None = None  # the folder made for a lone .db3
        self._any: Any = None
        self._listed: Rosbag2Listing | None = None  # from metadata.yaml
        try:
            if kind == "rosbag2":
                self._listed = open_rosbag2(bag_root(self.path))
            if self._listed is None:
                self._rosbags()
        except BaseException:
            self.close()
            raise
        self.listed_by = f"its {METADATA}" if self._listed is not None else "the bag"

    @property
    def rosbags_opened(self) -> bool:
        """Whether rosbags' reader was opened (it scans a sqlite3 storage on opening)."""
        return self._any is not None

    def _rosbags(self) -> Any:
        """rosbags' reader, opened on first use."""
        if self._any is None:
            if self.kind == "db3":
                self._tmp = self._tmp or db3_folder(self.path)
                target = self._tmp
            else:
                target = bag_root(self.path)
            self._any = open_anyreader(target)
        return self._any

    def topics(self) -> list[TopicInfo]:
        if self._listed is not None:
            return [
                TopicInfo(topic, mt, n, self.path) for topic, (mt, n) in self._listed.topics.items()
            ]
        return [
            TopicInfo(topic, info.msgtype or "?", int(info.msgcount), self.path)
            for topic, info in self._any.topics.items()
        ]

    def storage(self) -> tuple[str, list[Path]] | None:
        """The storage plugin and files of a bag without message/file compression whose
        storages are all of one plugin; None for anything else."""
        if self._listed is not None:
            return self._listed.storage, self._listed.files
        from rosbags.rosbag2.storage_mcap import McapReader
        from rosbags.rosbag2.storage_sqlite3 import Sqlite3Reader

        for name, plugin in (("sqlite3", Sqlite3Reader), ("mcap", McapReader)):
            files = self._storage_files(plugin)
            if files is not None:
                return name, files
        return None

    def _storage_files(self, plugin: type[Any]) -> list[Path] | None:
        if not self._any.is2:
            return None
        files = []
        for bag in self._any.readers:
            storages = getattr(bag.storage, "storages", [bag.storage])  # a folder, or one file
            if bag.compression_mode or not all(
                isinstance(s, plugin) and isinstance(s.path, Path) for s in storages
            ):
                return None
            files += [s.path for s in storages]
        return files

    def indexed(self, infos: list[TopicInfo]) -> IndexPlan | None:
        found = self.storage()
        if found is None or not found[1]:
            return None
        storage, files = found
        return STORAGE_PLUGINS[storage](files, infos)

    def raw(self, infos: list[TopicInfo], progress: Progress) -> dict[str, RawTopic]:
        found = self.storage()
        if found is None or found[0] != "sqlite3":
            return anyreader_raw(self._rosbags(), infos, progress)
        out: dict[str, RawTopic] = {i.topic: ([], [], None) for i in infos}
        topics = list(out)
        n = 0
        batches: Iterable[Batch] = sqlite_batches(found[1], topics)
        for batch in batches:  # one topic and file each, in row order
            raws, logs, _ = out[topics[int(batch.conn[0])]]
            order = np.argsort(batch.log_ns, kind="stable")  # by log time, as rosbags
            buf = batch.buf.tobytes()
            raws.extend(buf[batch.starts[i] : batch.ends[i]] for i in order)
            logs.extend(batch.log_ns[order].tolist())
            n += len(order)
        progress.advance(n % 4096)
        return out

    def deserialize(self, info: TopicInfo, raws: list[bytes], schema: Any) -> list[Any]:
        reader = self._rosbags()
        return [reader.deserialize(x, info.msgtype) for x in raws]

    def close(self) -> None:
        if self._any is not None:
            with contextlib.suppress(Exception):
                self._any.close()
            self._any = None
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None
