"""ROS1 bags at the speed of the disk: messages located through rosbags' chunk index and
sliced out of each decompressed chunk in bulk (no per-message deserialization); the
fixed-layout fields are then gathered with numpy (:mod:`layout`).
"""

from __future__ import annotations

from collections.abc import Iterator
from itertools import chain
from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.ingest.sources import layout
from qsls.pipeline.ingest.sources.layout import Batch

_BATCH_BYTES = 8 << 20
"""Bytes of chunk data (decompressed) decoded at once: bounds the reader's memory."""


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


_Entries = dict[int, list[tuple[int, np.ndarray]]]


def _chunk_entries(reader1: Any, conn_ids: set[int]) -> _Entries:
    """``{chunk position: [(conn, entries), ...]}`` of the wanted connections: the arrays of
    :func:`open_ros1` (by reference: :func:`_chunk_rows` reads them chunk by chunk), or rows
    ``(time, offset)`` from rosbags' ``IndexData`` of a plain rosbags reader."""
    out: _Entries = {}
    arrays = getattr(reader1, "index_arrays", None)
    for c in sorted(conn_ids):
        if arrays is not None:
            for pos, e in arrays.get(c, []):
                out.setdefault(int(pos), []).append((c, e))
            continue
        entries = reader1.indexes[c]
        a = np.fromiter(chain.from_iterable(entries), dtype=np.int64, count=3 * len(entries))
        a = a.reshape(-1, 3)  # time, chunk position, offset
        a = a[np.argsort(a[:, 1], kind="stable")]
        cut = np.flatnonzero(a[1:, 1] != a[:-1, 1]) + 1
        for part in np.split(a, cut) if len(a) else []:
            out.setdefault(int(part[0, 1]), []).append((c, part[:, [0, 2]]))
    return out


def _chunk_rows(parts: list[tuple[int, np.ndarray]]) -> np.ndarray:
    """The rows ``(time, offset, conn)`` of one chunk in ``(time, offset)`` order, from its
    :func:`_chunk_entries` list."""
    rows = []
    for c, e in parts:
        if e.dtype == _ENTRY:
            t = e["sec"].astype(np.int64) * 1_000_000_000 + e["nsec"]
            off = e["offset"].astype(np.int64)
        else:
            t, off = e[:, 0], e[:, 1]
        rows.append(np.column_stack([t, off, np.full(len(e), c, np.int64)]))
    r = rows[0] if len(rows) == 1 else np.concatenate(rows)
    return r[np.lexsort((r[:, 1], r[:, 0]))]


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
    """The messages of ``conn_ids``, located through rosbags' ROS1 index (module docstring),
    chunk by chunk in file order (within a chunk in ``(time, offset)`` order), in batches of
    about ``_BATCH_BYTES``: memory stays bounded whatever the bag's length.

    Uncompressed bags are read through memory maps of windows of the file (about
    ``_BATCH_BYTES`` each, unmapped when the next is asked for: only the pages holding
    wanted records are read, and they leave the resident set with their window); compressed
    chunks are decompressed once each into one reused buffer. A batch's ``buf`` is only
    valid until the next batch is asked for. Raises :class:`layout.LayoutError` when a
    record is not where the index says.
    """
    from rosbags.rosbag1.reader import decompressors

    entries = _chunk_entries(reader1, conn_ids)
    if not entries:
        return
    chunks = reader1.chunks
    order = sorted(entries)  # chunk positions: file order
    if all(chunks[c].decompressor is decompressors["none"] for c in order):
        yield from _mapped_batches(reader1, entries, order)
        return
    # decompressed chunks are copied into one reused buffer (fresh memory for every batch
    # would cost more in page faults than the decompression itself)
    work = np.empty(_BATCH_BYTES + max(chunks[c].datasize for c in order) * 4, np.uint8)
    base: list[int] = []
    rows: list[np.ndarray] = []
    size = 0

    def flush() -> Batch:
        buf = work[:size]
        part = np.concatenate(rows)
        rec = np.repeat(np.array(base), [len(r) for r in rows]) + part[:, 1]
        starts, ends = _records(buf, rec, part[:, 0], part[:, 2])
        return Batch(buf, starts, ends, part[:, 0], part[:, 2])

    with open(reader1.path, "rb") as fh:
        for c in order:
            ch = chunks[c]
            fh.seek(ch.datapos)
            raw = ch.decompressor(fh.read(ch.datasize))
            if size + len(raw) > len(work) or (rows and size >= _BATCH_BYTES):
                if rows:
                    yield flush()
                base, rows, size = [], [], 0
                if len(raw) > len(work):
                    work = np.empty(len(raw), np.uint8)
            work[size : size + len(raw)] = np.frombuffer(raw, np.uint8)
            base.append(size)
            rows.append(_chunk_rows(entries.pop(c)))
            size += len(raw)
    if rows:
        yield flush()


def _mapped_batches(reader1: Any, entries: _Entries, order: list[int]) -> Iterator[Batch]:
    """Uncompressed chunks: one batch per window of consecutive chunks spanning about
    ``_BATCH_BYTES`` of the file, read through a memory map of that window alone."""
    chunks = reader1.chunks
    k = 0
    while k < len(order):
        lo = chunks[order[k]].datapos
        group = [order[k]]
        k += 1
        while (
            k < len(order)
            and chunks[order[k]].datapos + chunks[order[k]].datasize - lo <= _BATCH_BYTES
        ):
            group.append(order[k])
            k += 1
        last = chunks[group[-1]]
        span = last.datapos + last.datasize - lo
        if lo + span > reader1.path.stat().st_size:
            raise layout.LayoutError("chunk data beyond the end of the file")
        # a plain ndarray over the map: cheaper gathers
        buf = np.memmap(reader1.path, np.uint8, "r", offset=lo, shape=(span,)).view(np.ndarray)
        parts = [_chunk_rows(entries.pop(c)) for c in group]
        rows = parts[0] if len(parts) == 1 else np.concatenate(parts)
        base = np.repeat(
            np.array([chunks[c].datapos - lo for c in group], np.int64), [len(p) for p in parts]
        )
        starts, ends = _records(buf, base + rows[:, 1], rows[:, 0], rows[:, 2])
        yield Batch(buf, starts, ends, rows[:, 0], rows[:, 2])
        del buf, starts, ends, rows, parts


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
