"""Write a ROS1 ``.bag`` with rosbags' ``rosbag1.Writer`` (ROS1 Noetic types; chunk
compression ``lz4`` or ``bz2`` optional). docs/ingest.md#formats."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from qsls.pipeline.ingest.sources.messages import MessageBuilder, Stream, log_order, stream_types


def write_ros1(
    path: Path, streams: Sequence[Stream], compression: str | None, chunk_size: int | None
) -> None:
    from rosbags.rosbag1 import Writer

    b = MessageBuilder(ros1=True)
    w = Writer(path)
    if chunk_size:
        w.chunk_threshold = int(chunk_size)
    if compression:
        w.set_compression(Writer.CompressionFormat[compression.upper()])
    with w:
        conns = {
            t: w.add_connection(t, mt, typestore=b.ts) for t, mt in stream_types(streams).items()
        }
        for k, i, log in log_order(streams):
            s = streams[k]
            w.write(conns[s.topic], log, b.serialize(b.message(s, i), s.msgtype))
