"""rosbag2 sqlite3 storage read with SQL: a topic's fields in one query per database file.

rosbags' reader, on opening a sqlite3 bag, counts the messages of every topic (a scan of the
whole ``messages`` table, whose rows hold the message data), builds a typestore (importing
a ROS 2 distribution's types) and then yields one message at a time. For the fixed-layout
pose topics none of that is needed: :mod:`listing` takes the topics, their types and
counts from the bag's ``metadata.yaml`` (what rosbags reads them from), and this module
fetches each wanted topic as one :class:`Batch` per database file, which :mod:`layout`
decodes for the whole topic at once (docs/ingest.md#speed).

Handing a row to Python costs more than SQLite's scan of it (a tuple, an int and a bytes
object per message: 0.15 s for 200 000 rows against 0.03 s for the scans), so the
fixed-layout read (:func:`sqlite_batches` with ``msgtypes``) lets SQLite build the buffer:

1. the topic's first message is decoded in full and gives the :class:`layout.Trim`, the
   byte ranges of a message that hold the fields read (the covariances and what follows
   the last field are left out: an Odometry's 724 bytes become 148; where its covariances
   are not all zero, the query (which also returns each covariance block's largest value)
   is run again with their diagonals kept: 244 bytes);
2. one aggregate query concatenates those ranges of every message (``group_concat`` of
   ``substr``), the log times as text (parsed by numpy at once), the message count and the
   smallest and largest message length. The rows reach the aggregate in the order SQLite
   scans them (row order for its table scan; SQL promises no order, and none is needed:
   each record and its log time come from the same row in the same step, and the reader
   sorts by log time);
3. the result is checked against the plan: every message as long as the first, and the
   trim's ``fixed`` bytes (encapsulation, every string with its length word) equal to the
   first message's, so every message has its fields at the first one's offsets. A topic
   that fails (its frame names change, say) is fetched row by row instead.

A result longer than 4 MB (``_QUERY_BYTES``: the reader's memory stays bounded whatever the
bag's length) or than SQLite's length limit (1 GB by default) is avoided by querying ranges
of row ids sized on the first message (a range whose messages are longer, which SQLite
refuses to concatenate, is fetched row by row). The row-by-row fetch
(:func:`sqlite_batches` without ``msgtypes``, or a topic that failed the check) takes each
``(timestamp, data)`` row in one query per topic.

Anything else (compressed bags, another storage, a metadata file rosbags would refuse) is
left to rosbags' reader, which also reports what is wrong with it.
"""

from __future__ import annotations

import contextlib
import gc
import sqlite3
import warnings
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from qsls.pipeline.ingest.sources import layout
from qsls.pipeline.ingest.sources.layout import Batch

_MMAP_BYTES = 1 << 40
_STAMP_CHARS = 21  # a log time as text (up to 19 digits and a sign) and its comma
_QUERY_BYTES = 4 << 20
"""Bytes of trimmed records (and their log times as text) one query returns at most."""


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


def sqlite_batches(
    files: list[Path], topics: list[str], msgtypes: Sequence[str] | None = None
) -> Iterator[Batch]:
    """The messages of each of ``topics`` in each database file (``conn`` = the topic's
    index in ``topics``): whole, or, given each topic's fixed-layout ``msgtypes``, as
    trimmed records (``Batch.trimmed``) where every message has the first one's layout
    (module docstring). A topic's first message that does not have its type's layout
    raises :class:`layout.LayoutError`."""
    for db in files:
        con = _connect(Path(db))
        try:
            ids: dict[int, list[int]] = {}
            for tid, name in con.execute("SELECT id, name FROM topics"):
                if name in topics:
                    ids.setdefault(topics.index(name), []).append(int(tid))
            for k, tids in sorted(ids.items()):
                where = f"topic_id IN ({','.join('?' * len(tids))})"
                if msgtypes is None:
                    yield from _rows(con, where, tids, k, None)
                else:
                    yield from _trimmed(con, where, tids, k, msgtypes[k])
        finally:
            con.close()


def _connect(db: Path) -> sqlite3.Connection:
    """``db`` opened read-only, its pages read through a memory map: not copied by one
    read() each into SQLite's own cache (a scan of the 107 MB benchmark bag 33 -> 17 ms of
    CPU; SQLite caps the map at its compile-time maximum, 2 GB by default)."""
    con = sqlite3.connect(f"file:{db.resolve()}?mode=ro", uri=True)
    con.execute(f"PRAGMA mmap_size = {_MMAP_BYTES}")
    return con


def _unmap(con: sqlite3.Connection) -> None:
    """Drop SQLite's memory map of the database (remapped by the next query): the pages a
    query read leave the resident set with it, so a scan of the whole file in ranges holds
    one range's pages, not the file's."""
    con.execute("PRAGMA mmap_size = 0")
    con.execute(f"PRAGMA mmap_size = {_MMAP_BYTES}")


def _rows(
    con: sqlite3.Connection, where: str, args: list[int], k: int, ids: tuple[int, int] | None
) -> Iterator[Batch]:
    """The topic's ``(timestamp, data)`` rows (those with ids in ``ids``, else all) as one
    batch of whole messages, back to back in row order: a topic whose messages all have one
    length is then decoded through one strided view (:func:`layout._words`)."""
    if ids is not None:
        where, args = f"{where} AND id BETWEEN ? AND ?", [*args, *ids]
    query = f"SELECT timestamp, data FROM messages WHERE {where} ORDER BY id"
    with _gc_paused():
        rows = con.execute(query, args).fetchall()
        columns = tuple(zip(*rows, strict=True))
        del rows
    if not columns:
        return
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


def _trimmed(
    con: sqlite3.Connection, where: str, args: list[int], k: int, msgtype: str
) -> Iterator[Batch]:
    """The topic as trimmed records, one batch per range of row ids; a range whose messages
    do not all have the first message's layout is fetched whole by :func:`_rows`."""
    first = con.execute(
        f"SELECT data FROM messages WHERE {where} ORDER BY id LIMIT 1", args
    ).fetchone()
    if first is None:
        return
    # lean records (no covariances) unless the range's covariances are not all zero: the
    # lean query also returns the largest of each covariance block (blobs compare bytewise,
    # so only all-zero blocks give an all-zero largest), and a range with one that is not
    # is fetched again with their diagonals (244 of an Odometry's 724 bytes against 148)
    lean = layout.plan_trim(bytes(first[0]), msgtype, "cdr", lean=True)
    full = layout.plan_trim(bytes(first[0]), msgtype, "cdr") if lean.covariances else lean
    query = _aggregate(lean, where, lean.covariances)
    query_full = _aggregate(full, where, ())
    # two subqueries: min and max in one aggregate would scan the table instead of two
    # lookups at the ends of its b-tree
    lo, hi = con.execute(
        "SELECT (SELECT min(id) FROM messages), (SELECT max(id) FROM messages)"
    ).fetchone()
    # ids per query: the record and stamp texts stay within half SQLite's length limit, and
    # within _QUERY_BYTES (the reader's memory is bounded whatever the bag's length)
    limit = min(con.getlimit(sqlite3.SQLITE_LIMIT_LENGTH) // 2, _QUERY_BYTES)
    step = max(1, limit // (full.size + _STAMP_CHARS))
    for a in range(lo, hi + 1, step):
        b = min(a + step - 1, hi)
        trim = lean
        try:
            n, shortest, longest, blob, stamps, *largest = con.execute(
                query, [*args, a, b]
            ).fetchone()
            if any(m is not None and any(bytes(m)) for m in largest):
                trim = full
                n, shortest, longest, blob, stamps = con.execute(
                    query_full, [*args, a, b]
                ).fetchone()
        except sqlite3.DataError:  # "string or blob too big": messages longer than the first
            yield from _rows(con, where, args, k, (a, b))
            continue
        if not n:
            continue
        batch = _records(n, shortest, longest, blob, stamps, trim, k)
        del blob, stamps
        if batch is None:
            yield from _rows(con, where, args, k, (a, b))
        else:
            yield batch
        del batch
        _unmap(con)


def _aggregate(trim: layout.Trim, where: str, largest: tuple[tuple[int, int], ...]) -> str:
    """The aggregate query of a range of row ids: count, shortest and longest message, the
    trimmed records concatenated, the log times as text, and the largest value of each
    message byte range in ``largest``."""
    whole = trim.spans == ((0, trim.length),)  # a message read whole: no copy per row
    record = (
        "data" if whole else "||".join(f"substr(data, {a + 1}, {b - a})" for a, b in trim.spans)
    )
    extra = "".join(f", max(substr(data, {a + 1}, {b - a}))" for a, b in largest)
    # concatenation and group_concat give TEXT (the bytes unchanged): CAST makes it a blob
    return (
        "SELECT count(*), min(length(data)), max(length(data)),"
        f" CAST(group_concat({record}, x'') AS BLOB), group_concat(timestamp){extra}"
        f" FROM messages WHERE {where} AND id BETWEEN ? AND ?"
    )


def _records(
    n: int,
    shortest: int,
    longest: int,
    blob: bytes,
    stamps: str,
    trim: layout.Trim,
    k: int,
) -> Batch | None:
    """The batch of ``n`` trimmed records in ``blob`` with their log times ``stamps`` (text);
    None unless every message has the planned layout (module docstring, step 3)."""
    if shortest != trim.length or longest != trim.length or len(blob) != n * trim.size:
        return None
    rec = np.frombuffer(blob, dtype=np.uint8).reshape(n, trim.size)
    ref = np.frombuffer(trim.record, dtype=np.uint8)
    for a, b in trim.fixed:
        if not np.array_equal(rec[:, a:b], np.broadcast_to(ref[a:b], (n, b - a))):
            return None
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpy warns, not raises, on text it cannot parse
        try:
            log_ns = np.fromstring(stamps, dtype=np.int64, sep=",")
        except (ValueError, DeprecationWarning):
            return None
    if len(log_ns) != n:
        return None
    ends = trim.size * np.arange(1, n + 1, dtype=np.int64)
    return Batch(
        buf=rec.reshape(-1),
        starts=ends - trim.size,
        ends=ends,
        log_ns=log_ns,
        conn=np.full(n, k, dtype=np.int64),
        trimmed="lean" if trim.lean else True,
    )
