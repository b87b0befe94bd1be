"""Write a plain ``.mcap`` file with the ``mcap`` package: ``ros2msg`` schemas and ``cdr``
messages, the way ``ros2 bag record -s mcap`` and Foxglove write them (chunk compression
``zstd``/``lz4`` optional). docs/ingest.md#formats."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from qsls.pipeline.ingest.sources.messages import MessageBuilder, Stream, log_order, stream_types


def write_mcap(
    path: Path, streams: Sequence[Stream], compression: str | None, chunk_size: int | None
) -> None:
    """Write ``streams`` as a plain MCAP file at ``path`` (``chunk_size`` bytes per chunk)."""
    from mcap.writer import CompressionType, Writer

    b = MessageBuilder(ros1=False)
    ctype = CompressionType[compression.upper()] if compression else CompressionType.NONE
    with open(path, "wb") as fh:
        w = Writer(fh, compression=ctype, chunk_size=chunk_size or 1 << 20)
        w.start(profile="ros2", library="qsls")
        channels: dict[str, int] = {}
        for topic, mt in stream_types(streams).items():
            msgdef, _ = b.ts.generate_msgdef(mt, ros_version=2)
            schema = w.register_schema(name=mt, encoding="ros2msg", data=msgdef.encode())
            channels[topic] = w.register_channel(
                topic=topic, message_encoding="cdr", schema_id=schema
            )
        seq: dict[str, int] = {}
        for k, i, log in log_order(streams):
            s = streams[k]
            n = seq.get(s.topic, 0)
            seq[s.topic] = n + 1
            data = b.serialize(b.message(s, i), s.msgtype)
            w.add_message(channels[s.topic], log_time=log, data=data, publish_time=log, sequence=n)
        w.finish()
