"""ROS1 bags at the speed of the disk: messages located through rosbags' chunk index and
sliced out of each decompressed chunk in bulk (no per-message deserialization); the
fixed-layout fields are then gathered with numpy (:mod:`layout`).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from itertools import chain
from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.ingest.sources import layout

_BATCH_BYTES = 64 << 20  # decompressed bytes decoded at once (bounds memory on big bags)


@dataclass(frozen=True)
class Batch:
    """Messages located in one buffer: message ``i`` is ``buf[starts[i]:ends[i]]``
    (``trimmed``: records cut by a :class:`layout.Trim`, not whole messages)."""

    buf: np.ndarray
    starts: np.ndarray
    ends: np.ndarray
    log_ns: np.ndarray
    conn: np.ndarray
    trimmed: bool = False


_ENTRY = np.dtype([("sec", "<u4"), ("nsec", "<u4"), ("offset", "<u4")])


def open_ros1(path: Path) -> Any:
    """rosbags' ROS1 reader, opened, with its message index read by numpy instead of one
    Python object per message.

    ``rosbags.rosbag1.Reader.open`` checks the bag (magic, version, encryption, index
    position) and reads its connections, chunk infos and chunk headers; after each chunk it
    calls ``read_index_data`` for every connection in the chunk, which builds one
    ``IndexData`` per message (0.16 s for 200 000 messages) and sorts them. Here that one
    method reads the same record (rosbags' header parser, ``op`` = index data, ``ver`` 1,
    ``count`` entries of ``uint32 sec, nsec, offset``) as one array per connection and
    chunk, kept in ``index_arrays`` (``reader.indexes`` stays empty); the entries' count
    must equal what the chunk info says. Everything else is rosbags' reader.
    """
    from rosbags.rosbag1.reader import Header, Reader, ReaderError, RecordType, read_uint32

    class NumpyIndexReader(Reader):
        index_arrays: dict[int, list[tuple[int, np.ndarray]]]

        def read_index_data(self, pos: int, indexes: Any) -> None:
            assert self.bio is not None
            header = Header.read(self.bio, RecordType.IDXDATA)
            if header.get_uint32("ver") != 1:
                raise ReaderError("IDXDATA version is not supported.")
            conn, count = header.get_uint32("conn"), header.get_uint32("count")
            size = read_uint32(self.bio)
            data = self.bio.read(size)
            infos = self.__dict__.setdefault("_infos", {c.pos: c for c in self.chunk_infos})
            counted = infos[pos].connection_counts.get(conn) if pos in infos else None
            if size != 12 * count or len(data) != size or counted != count:
                raise ReaderError("index data does not match its chunk info")
            self.index_arrays.setdefault(conn, []).append((pos, np.frombuffer(data, _ENTRY)))

    reader = NumpyIndexReader(path)
    reader.index_arrays = {}
    reader.open()
    return reader


def _index(reader1: Any, conn_ids: set[int]) -> np.ndarray:
    """rows ``(time, chunk_pos, offset, conn)`` of the reader's index, in time order: the
    arrays of :func:`open_ros1`, or rosbags' ``IndexData`` of a plain rosbags reader."""
    parts = []
    arrays = getattr(reader1, "index_arrays", None)
    for c in sorted(conn_ids):
        if arrays is not None:
            for pos, e in arrays.get(c, []):
                t = e["sec"].astype(np.int64) * 1_000_000_000 + e["nsec"]
                parts.append(np.column_stack([t, np.full(len(e), pos, np.int64),
                                              e["offset"].astype(np.int64),
                                              np.full(len(e), c, np.int64)]))  # fmt: skip
            continue
        entries = reader1.indexes[c]
        a = np.fromiter(chain.from_iterable(entries), dtype=np.int64, count=3 * len(entries))
        a = a.reshape(-1, 3)
        parts.append(np.column_stack([a, np.full(len(a), c, dtype=np.int64)]))
    idx = np.concatenate(parts) if parts else np.zeros((0, 4), np.int64)
    return idx[np.lexsort((idx[:, 2], idx[:, 1], idx[:, 0]))]


def _records(
    buf: np.ndarray, rec: np.ndarray, times: np.ndarray, conns: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(starts, ends) of the message data of the records at ``rec``, checked against the index.

    A record is ``uint32 header_len``, header fields (``uint32 len`` + ``name=value``),
    ``uint32 data_len``, data. The op code (2: message data), connection id and time in
    every header must equal what the index says.
    """
    if len(rec) == 0:
        return rec, rec
    hlen = layout._u32(buf, rec)
    if np.any(hlen != hlen[0]):
        raise layout.LayoutError("record headers of different lengths")
    h0 = int(hlen[0])
    fields = _header_fields(bytes(buf[int(rec[0]) + 4 : int(rec[0]) + 4 + h0]))
    if not {"op", "conn", "time"} <= set(fields):
        raise layout.LayoutError("record header without op/conn/time")
    # each record's header and data length in one copy (one pass over the records, not four)
    head = layout._words(buf, rec, 4 + h0 + 4, "u1")
    if not np.all(head[:, 4 + fields["op"]] == 2):
        raise layout.LayoutError("index points at a record that is not message data")
    if not np.array_equal(layout.column(head, 4 + fields["conn"], "<u4"), conns):
        raise layout.LayoutError("record of another connection than the index says")
    sec = layout.column(head, 4 + fields["time"], "<u4").astype(np.int64)
    nsec = layout.column(head, 8 + fields["time"], "<u4")
    if not np.array_equal(sec * 1_000_000_000 + nsec, times):
        raise layout.LayoutError("record time differs from the index")
    starts = rec + 8 + h0
    ends = starts + layout.column(head, 4 + h0, "<u4").astype(np.int64)
    if ends.max() > len(buf):
        raise layout.LayoutError("message data beyond the chunk")
    return starts, ends


def ros1_batches(reader1: Any, conn_ids: set[int]) -> Iterator[Batch]:
    """The messages of ``conn_ids``, located through rosbags' ROS1 index (module docstring).

    Uncompressed bags give one batch over a memory map of the file; compressed chunks are
    decompressed once each and grouped into batches of about 64 MB. Raises
    :class:`layout.LayoutError` when a record is not where the index says.
    """
    from rosbags.rosbag1.reader import decompressors

    idx = _index(reader1, conn_ids)
    if len(idx) == 0:
        return
    chunks = reader1.chunks
    chunk = np.sort(idx[:, 1])
    uniq = chunk[np.r_[True, chunk[1:] != chunk[:-1]]]  # np.unique would import numpy.ma
    if all(chunks[int(c)].decompressor is decompressors["none"] for c in uniq):
        buf = np.memmap(reader1.path, dtype=np.uint8, mode="r")
        datapos = np.array([chunks[int(c)].datapos for c in uniq], dtype=np.int64)
        rec = datapos[np.searchsorted(uniq, idx[:, 1])] + idx[:, 2]
        starts, ends = _records(buf, rec, idx[:, 0], idx[:, 3])
        yield Batch(buf, starts, ends, idx[:, 0], idx[:, 3])
        return
    # messages grouped by chunk (stable: time order within a chunk), chunks in file order
    by_chunk = np.argsort(idx[:, 1], kind="stable")
    sidx = idx[by_chunk]
    bounds = np.searchsorted(sidx[:, 1], uniq)
    bounds = np.append(bounds, len(sidx))
    # decompressed chunks are copied into one reused buffer (fresh memory for every batch
    # would cost more in page faults than the decompression itself)
    work = np.empty(_BATCH_BYTES + max(chunks[int(c)].datasize for c in uniq) * 4, np.uint8)
    base: list[int] = []
    rows: list[np.ndarray] = []
    size = 0

    def flush() -> Batch:
        buf = work[:size]
        part = np.concatenate(rows)
        rec = np.repeat(np.array(base), [len(r) for r in rows]) + part[:, 2]
        starts, ends = _records(buf, rec, part[:, 0], part[:, 3])
        return Batch(buf, starts, ends, part[:, 0], part[:, 3])

    with open(reader1.path, "rb") as fh:
        for k, c in enumerate(uniq.tolist()):
            ch = chunks[c]
            fh.seek(ch.datapos)
            raw = ch.decompressor(fh.read(ch.datasize))
            if size + len(raw) > len(work):
                if rows:
                    yield flush()
                base, rows, size = [], [], 0
                if len(raw) > len(work):
                    work = np.empty(len(raw), np.uint8)
            work[size : size + len(raw)] = np.frombuffer(raw, np.uint8)
            base.append(size)
            rows.append(sidx[bounds[k] : bounds[k + 1]])
            size += len(raw)
    if rows:
        yield flush()


def ros1_slices(
    reader1: Any, conn_ids: set[int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """All messages of ``conn_ids`` in one buffer, in time order: ``(buf, starts, ends, log_ns)``.

    For tests and small bags (it copies every message); readers use :func:`ros1_batches`.
    """
    pieces: list[tuple[int, bytes]] = []
    for b in ros1_batches(reader1, conn_ids):
        for s, e, t in zip(b.starts.tolist(), b.ends.tolist(), b.log_ns.tolist(), strict=True):
            pieces.append((t, bytes(b.buf[s:e])))
    pieces.sort(key=lambda x: x[0])
    buf, starts, ends = layout.concat([p for _, p in pieces])
    return buf, starts, ends, np.array([t for t, _ in pieces], dtype=np.int64)


def _header_fields(raw: bytes) -> dict[str, int]:
    """Offsets (within the header) of each field's value."""
    out = {}
    i = 0
    while i + 4 <= len(raw):
        n = int.from_bytes(raw[i : i + 4], "little")
        field = raw[i + 4 : i + 4 + n]
        name, _, _ = field.partition(b"=")
        out[name.decode(errors="replace")] = i + 4 + len(name) + 1
        i += 4 + n
    return out
