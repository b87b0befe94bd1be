"""Write flight logs as real bags: ROS1, ROS2 (sqlite3 or MCAP storage) and plain MCAP.

Used by the simulator to record its flights, by the tests to write fixtures with known
content, and by the benchmark. Each format's writer sits beside its reader
(:mod:`.ros1.writer`, :mod:`.rosbag2.writer`, :mod:`.mcap.writer`; the TUM text writer in
:mod:`.text.writer`); every message goes through the official writers and rosbags'
typestore (:mod:`.messages`).

Formats (``FORMATS``):

- ``ros1``: one ``.bag`` file (chunk compression ``lz4`` or ``bz2`` optional).
- ``ros2-sqlite`` / ``ros2-mcap``: a rosbag2 folder (``metadata.yaml`` version 9) with one
  ``.db3`` or ``.mcap`` storage file (``zstd`` message compression optional).
- ``mcap``: a single ``.mcap`` file, ``ros2msg`` schemas and ``cdr`` messages, the way
  ``ros2 bag record -s mcap`` and Foxglove write them (chunk compression ``zstd``/``lz4``).

The bag appears atomically: it is written under a temporary name beside ``path`` and
renamed into place, replacing an existing bag of the same name.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Sequence
from pathlib import Path

from qsls.pipeline.core.locks import make_temporary
from qsls.pipeline.ingest.sources.mcap.writer import write_mcap
from qsls.pipeline.ingest.sources.messages import Stream, check_streams
from qsls.pipeline.ingest.sources.ros1.writer import write_ros1
from qsls.pipeline.ingest.sources.rosbag2.writer import write_rosbag2

FORMATS = ("ros1", "ros2-sqlite", "ros2-mcap", "mcap")
STORAGES = {"ros2-sqlite": "sqlite3", "ros2-mcap": "mcap"}
"""The rosbag2 formats and their storage plugins."""

_COMPRESSIONS = {
    "ros1": (None, "lz4", "bz2"),
    "ros2-sqlite": (None, "zstd"),
    "ros2-mcap": (None, "zstd"),
    "mcap": (None, "zstd", "lz4"),
}


def write_bag(
    path: Path,
    streams: Sequence[Stream],
    fmt: str,
    *,
    compression: str | None = None,
    chunk_size: int | None = None,
) -> Path:
    """Write ``streams`` into a bag at ``path`` in format ``fmt`` (one of ``FORMATS``).

    ``ros1`` and ``mcap`` give a file, ``ros2-sqlite`` and ``ros2-mcap`` a rosbag2 folder.
    ``chunk_size`` (bytes, ``ros1`` and ``mcap``) overrides the writers' 1 MiB chunks.
    Returns ``path``. Atomic: nothing appears at ``path`` unless the whole bag was written.
    """
    path = Path(path)
    if fmt not in FORMATS:
        raise ValueError(f"unknown bag format {fmt!r}; use one of {', '.join(FORMATS)}")
    if compression not in _COMPRESSIONS[fmt]:
        allowed = ", ".join(c for c in _COMPRESSIONS[fmt] if c)
        raise ValueError(f"compression {compression!r} not available for {fmt}; use {allowed}")
    check_streams(streams)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmpdir = make_temporary(path)
    tmp = tmpdir / path.name
    try:
        if fmt == "ros1":
            write_ros1(tmp, streams, compression, chunk_size)
        elif fmt == "mcap":
            write_mcap(tmp, streams, compression, chunk_size)
        else:
            write_rosbag2(tmp, streams, STORAGES[fmt], compression)
        if path.is_dir():
            shutil.rmtree(path)
        os.replace(tmp, path)
    finally:
        shutil.rmtree(tmpdir, ignore_errors=True)
    return path
