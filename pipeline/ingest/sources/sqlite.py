"""rosbag2 sqlite3 storage read with SQL: one query per wanted topic and database file.

rosbags' reader, on opening a sqlite3 bag, counts the messages of every topic (a scan of the
whole ``messages`` table, whose rows hold the message data), builds a typestore (importing
a ROS 2 distribution's types) and then yields one message at a time. For the fixed-layout
pose topics none of that is needed: :mod:`listing` takes the topics, their types and
counts from the bag's ``metadata.yaml`` (what rosbags reads them from), and
:func:`sqlite_batches` fetches each wanted topic's ``(timestamp, data)`` rows in one query
per topic and file, in row order, as one buffer with every message's start and end (a
:class:`Batch`), which :mod:`layout` decodes for the whole topic at once.

Anything else (compressed bags, another storage, a metadata file rosbags would refuse) is
left to rosbags' reader, which also reports what is wrong with it.
"""

from __future__ import annotations

import contextlib
import gc
import sqlite3
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from qsls.pipeline.ingest.sources.ros1index import Batch

_MMAP_BYTES = 1 << 40


@contextlib.contextmanager
def _gc_paused() -> Iterator[None]:
    """No cyclic garbage collection meanwhile: the 200 000 row tuples of a fetch hold no
    cycles, yet their allocation triggers collections that walk them all (a third of the
    fetch's time)."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def sqlite_batches(files: list[Path], topics: list[str]) -> Iterator[Batch]:
    """The messages of each of ``topics`` in each database file as one :class:`Batch` (in row
    order, ``conn`` = the topic's index in ``topics``).

    One query per topic: its messages then lie back to back in the batch's buffer, and a
    topic whose messages all have one length (the frame names do not change) is decoded
    through one strided view (:func:`layout._words`). A single query for all topics costs
    the same (the table is scanned once instead of once per topic, but each row is handed
    to Python either way) and interleaves them.
    """
    for db in files:
        con = sqlite3.connect(f"file:{Path(db).resolve()}?mode=ro", uri=True)
        try:
            # pages read from a memory map, not copied by one read() each into SQLite's own
            # cache: a scan of the 107 MB benchmark bag 33 -> 17 ms of CPU (SQLite caps
            # the map at its compile-time maximum, 2 GB by default)
            con.execute(f"PRAGMA mmap_size = {_MMAP_BYTES}")
            ids: dict[int, list[int]] = {}
            for tid, name in con.execute("SELECT id, name FROM topics"):
                if name in topics:
                    ids.setdefault(topics.index(name), []).append(int(tid))
            for k, tids in sorted(ids.items()):
                marks = ",".join("?" * len(tids))
                query = (
                    f"SELECT timestamp, data FROM messages WHERE topic_id IN ({marks}) ORDER BY id"
                )
                with _gc_paused():
                    rows = con.execute(query, tids).fetchall()
                    columns = tuple(zip(*rows, strict=True))
                    del rows
                if not columns:
                    continue
                stamps, data = columns
                lengths = np.fromiter(map(len, data), dtype=np.int64, count=len(data))
                ends = np.cumsum(lengths)
                yield Batch(
                    buf=np.frombuffer(b"".join(data), dtype=np.uint8),
                    starts=ends - lengths,
                    ends=ends,
                    log_ns=np.array(stamps, dtype=np.int64),
                    conn=np.full(len(data), k, dtype=np.int64),
                )
        finally:
            con.close()
