"""A ROS1 ``.bag``: rosbags' ROS1 reader opened with its index read by numpy
(:func:`~.index.open_ros1`), whose fixed-layout topics are sliced out of the chunks in bulk
(:func:`~.index.ros1_batches`); rosbags' ``AnyReader`` only for the per-message path.
docs/ingest.md#formats.
"""

from __future__ import annotations

import contextlib
import shutil
from pathlib import Path
from typing import Any

from qsls.pipeline.core.progress import Progress
from qsls.pipeline.ingest.sources.anyreader import anyreader_raw, open_anyreader, temp_link
from qsls.pipeline.ingest.sources.base import IndexPlan, RawTopic, TopicInfo
from qsls.pipeline.ingest.sources.ros1.index import open_ros1, ros1_batches


class Ros1Reader:
    """An open ROS1 bag (:class:`~qsls.pipeline.ingest.sources.base.BagReader`)."""

    cdr = False
    listed_by = "the bag"

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._link: Path | None = None
        self._any: Any = None  # AnyReader (typestore, index as objects) only when needed
        try:
            self._ros1 = open_ros1(self._bag_path())
        except BaseException:
            self.close()
            raise

    def _bag_path(self) -> Path:
        """The bag under a ``.bag`` name (rosbags' readers go by the suffix)."""
        if self.path.suffix == ".bag":
            return self.path
        if self._link is None:
            self._link = temp_link(self.path, self.path.name + ".bag")
        return self._link

    @property
    def rosbags_opened(self) -> bool:
        """Whether rosbags' ``AnyReader`` was opened (the per-message path)."""
        return self._any is not None

    def _rosbags(self) -> Any:
        if self._any is None:
            self._any = open_anyreader(self._bag_path())
        return self._any

    def topics(self) -> list[TopicInfo]:
        return [
            TopicInfo(topic, info.msgtype or "?", int(info.msgcount), self.path)
            for topic, info in self._ros1.topics.items()
        ]

    def indexed(self, infos: list[TopicInfo]) -> IndexPlan:
        r1 = self._ros1
        ids = {i.topic: {c.id for c in r1.connections if c.topic == i.topic} for i in infos}
        conns = set().union(*ids.values())
        return ids, lambda: ros1_batches(r1, conns)

    def raw(self, infos: list[TopicInfo], progress: Progress) -> dict[str, RawTopic]:
        return anyreader_raw(self._rosbags(), infos, progress)

    def deserialize(self, info: TopicInfo, raws: list[bytes], schema: Any) -> list[Any]:
        reader = self._rosbags()
        return [reader.deserialize(x, info.msgtype) for x in raws]

    def close(self) -> None:
        for r in (getattr(self, "_ros1", None), self._any):
            if r is not None:
                with contextlib.suppress(Exception):
                    r.close()
        self._ros1 = self._any = None
        if self._link is not None:
            shutil.rmtree(self._link.parent, ignore_errors=True)
            self._link = None
