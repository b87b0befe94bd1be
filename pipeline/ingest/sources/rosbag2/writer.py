"""Write a rosbag2 folder with rosbags' ``rosbag2.Writer``: ``metadata.yaml`` version 9 and one
``.db3`` (sqlite3) or ``.mcap`` storage file, ROS2 Humble types, ``zstd`` message compression
optional. docs/ingest.md#formats."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from qsls.pipeline.ingest.sources.messages import MessageBuilder, Stream


def write_rosbag2(
    path: Path, streams: Sequence[Stream], storage: str, compression: str | None
) -> None:
    """Write ``streams`` as a rosbag2 folder at ``path`` with ``storage`` (``sqlite3``/``mcap``)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

    b = MessageBuilder(ros1=False)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    w = Writer(path, version=9, storage_plugin=plugin)
    if compression:
        w.set_compression(CompressionMode.MESSAGE, CompressionFormat[compression.upper()])
    with w:
        b.write_all(w, streams)
