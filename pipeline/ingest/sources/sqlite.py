"""rosbag2 sqlite3 storage read with SQL: one query per database file for every wanted topic.

rosbags' reader, on opening a sqlite3 bag, counts the messages of every topic (a scan of the
whole ``messages`` table, whose rows hold the message data), builds a typestore (importing
a ROS 2 distribution's types) and then yields one message at a time. For the fixed-layout
pose topics none of that is needed: :func:`open_sqlite_bag` takes the topics, their types
and counts from the bag's ``metadata.yaml`` (what rosbags reads them from), and
:func:`sqlite_batches` fetches the wanted topics' ``(topic_id, timestamp, data)`` rows in
one query per file, in row order, as one buffer with every message's start and end (a
:class:`Batch`), which :mod:`layout` decodes for the whole topic at once.

Anything else (compressed bags, another storage, a metadata file rosbags would refuse) is
left to rosbags' reader, which also reports what is wrong with it.
"""

from __future__ import annotations

import contextlib
import gc
import sqlite3
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path, PurePath

import numpy as np

from qsls.pipeline.ingest.sources.ros1index import Batch


@dataclass(frozen=True)
class SqliteBag:
    """An uncompressed sqlite3 rosbag2: its database files and ``{topic: (type, count)}``."""

    files: list[Path]
    topics: dict[str, tuple[str, int]]


def open_sqlite_bag(folder: Path) -> SqliteBag | None:
    """The bag in ``folder`` when its ``metadata.yaml`` describes an uncompressed sqlite3
    rosbag2 of CDR messages whose files all exist; None for anything else."""
    import yaml

    try:
        meta = yaml.safe_load((Path(folder) / "metadata.yaml").read_text())
        info = meta["rosbag2_bagfile_information"]
        if int(info["version"]) > 9 or info["storage_identifier"] != "sqlite3":
            return None
        if (info.get("compression_mode") or "none").lower() != "none":
            return None
        files = [Path(folder) / PurePath(p).name for p in info["relative_file_paths"]]
        topics: dict[str, tuple[str, int]] = {}
        for entry in info["topics_with_message_count"]:
            t = entry["topic_metadata"]
            if t["serialization_format"] != "cdr":
                return None
            prev = topics.get(t["name"], (t["type"], 0))
            if prev[0] != t["type"]:
                return None
            topics[t["name"]] = (t["type"], prev[1] + int(entry["message_count"]))
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError, AttributeError):
        return None
    if not files or not all(f.is_file() for f in files):
        return None
    return SqliteBag(files, topics)


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
    """The messages of ``topics`` in each database file as one :class:`Batch` (in row order,
    ``conn`` = the topic's index in ``topics``)."""
    for db in files:
        con = sqlite3.connect(f"file:{Path(db).resolve()}?mode=ro", uri=True)
        try:
            ids = {
                int(tid): topics.index(name)
                for tid, name in con.execute("SELECT id, name FROM topics")
                if name in topics
            }
            if not ids:
                continue
            marks = ",".join("?" * len(ids))
            query = (
                f"SELECT topic_id, timestamp, data FROM messages WHERE topic_id IN ({marks}) "
                "ORDER BY id"
            )
            with _gc_paused():
                rows = con.execute(query, list(ids)).fetchall()
                columns = tuple(zip(*rows, strict=True))
                del rows
        finally:
            con.close()
        if not columns:
            continue
        tids, stamps, data = columns
        lengths = np.fromiter(map(len, data), dtype=np.int64, count=len(data))
        ends = np.cumsum(lengths)
        label = np.zeros(max(ids) + 1, dtype=np.int64)
        label[list(ids)] = list(ids.values())
        yield Batch(
            buf=np.frombuffer(b"".join(data), dtype=np.uint8),
            starts=ends - lengths,
            ends=ends,
            log_ns=np.array(stamps, dtype=np.int64),
            conn=label[np.array(tids, dtype=np.int64)],
        )
