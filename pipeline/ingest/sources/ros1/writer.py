"""Write a ROS1 ``.bag`` with rosbags' ``rosbag1.Writer`` (ROS1 Noetic types; chunk
compression ``lz4`` or ``bz2`` optional). docs/ingest.md#formats."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from qsls.pipeline.ingest.sources.messages import MessageBuilder, Stream


def write_ros1(
    path: Path, streams: Sequence[Stream], compression: str | None, chunk_size: int | None
) -> None:
    """Write ``streams`` as a ROS1 bag at ``path`` (``chunk_size`` bytes per chunk, if given)."""
    from rosbags.rosbag1 import Writer

    b = MessageBuilder(ros1=True)
    w = Writer(path)
    if chunk_size:
        w.chunk_threshold = int(chunk_size)
    if compression:
        w.set_compression(Writer.CompressionFormat[compression.upper()])
    with w:
        b.write_all(w, streams)
