"""MCAP at the speed of the disk: whole chunks located through the summary, decompressed
once each, and the wanted channels' messages sliced out in bulk; the fixed-layout fields
are then gathered with numpy (:mod:`..layout`), as the ROS1 path does (:mod:`..ros1.index`).

An MCAP file (plain, or the storage file of a rosbag2 bag) ends with a summary: a
``ChunkIndex`` per chunk (where the chunk record is, its compression, and where the
``MessageIndex`` record of every channel in it is) plus channels, schemas and statistics.
Each ``MessageIndex`` lists ``(log_time, offset)`` of every message of one channel in one
chunk, the offset counted in the chunk's uncompressed records. So:

1. The summary is read with the ``mcap`` package (``McapReader.get_summary``).
2. The chunks holding a wanted channel are read in file order. Uncompressed chunks are
   memory-mapped (only the pages holding wanted messages are touched: camera images in the
   same chunks are skipped); compressed chunks are read with ``mcap.records.Chunk.read`` and
   decompressed once each with ``mcap.stream_reader.get_chunk_data_stream`` (zstd, lz4).
3. The wanted channels' ``MessageIndex`` records give the message offsets. Their entries
   are a packed ``(uint64 log_time, uint64 offset)`` array, read with ``np.frombuffer``
   (``MessageIndex.read`` costs 0.11 s per 100k entries in Python; a test checks the two
   agree entry for entry).
4. Every message record is checked against the index (op code ``MESSAGE``, channel id,
   log time) before its data is handed to :func:`layout.decode`.

Anything this path does not cover raises :class:`layout.LayoutError` before a message is
decoded wrongly, and the caller falls back to the ``mcap``/rosbags per-message readers: no
summary or no chunk index (an unindexed or truncated file), a chunk without message
indexes, a compression the ``mcap`` package cannot decompress, statistics that disagree
with the index, a record that is not where the index says.

Every chunk read is checked against the CRC its record carries (when the writer stored
one, i.e. not 0): a mismatch is refused with one ``InputError`` line naming the chunk (its
number in file order and its byte offset). That costs one ``zlib.crc32`` pass over the
chunk's uncompressed records (about 1 GB/s; the pages of an uncompressed chunk holding camera
images are then read too), cheap against a decompression.

A truncated file is refused, not read up to the damage: its footer and summary are gone,
and the per-message fallback stops with one ``InputError`` line naming the repair tool
(``mcap recover`` / ``ros2 bag reindex``); a partial flight read silently would look whole.
"""

from __future__ import annotations

import contextlib
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.core.errors import InputError
from qsls.pipeline.ingest.sources import layout
from qsls.pipeline.ingest.sources.base import TopicInfo
from qsls.pipeline.ingest.sources.layout import Batch
from qsls.pipeline.ingest.sources.msgtypes import normalize_type

_BATCH_BYTES = 8 << 20
"""Bytes of chunk records decoded at once (a window of the file, or decompressed): bounds
the reader's memory."""
_COMPRESSIONS = ("", "zstd", "lz4")
_MSG_HEAD = 1 + 8 + 2 + 4 + 8 + 8  # opcode, length, channel_id, sequence, log, publish
_IDX_HEAD = 1 + 8 + 2 + 4  # opcode, length, channel_id, records_length


@dataclass(frozen=True)
class Located:
    """One chunk holding wanted messages: where its wanted channels' message indexes are
    (``(channel id, label, index record offset)``, read when the chunk is decoded, so the
    index entries of the whole file are never held at once)."""

    chunk: Any  # mcap.records.ChunkIndex
    indexes: tuple[tuple[int, int, int], ...]
    number: int = 0  # the chunk's number in file order (1-based, for messages)

    def rows(self, buf: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(offsets, log_ns, channel, label)`` of the chunk's wanted messages, in offset
        order (int64; ``buf`` the file)."""
        parts = []
        for cid, label, at in self.indexes:
            idx = message_index(buf, at, cid)
            parts.append(np.column_stack([idx, np.full((len(idx), 2), (cid, label))]))
        r = parts[0] if len(parts) == 1 else np.concatenate(parts)
        r = r[np.argsort(r[:, 1], kind="stable")]
        return r[:, 1], r[:, 0], r[:, 2], r[:, 3]


def read_summary(path: Path) -> Any:
    """The ``mcap.summary.Summary`` of ``path`` (``LayoutError``: none, or unreadable)."""
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as fh:
            summary = make_reader(fh).get_summary()
    except Exception as exc:  # a truncated file has no footer: the fallback decides
        raise layout.LayoutError(f"no readable MCAP summary ({exc})") from None
    if summary is None:
        raise layout.LayoutError("MCAP file without a summary section")
    return summary


def message_index(buf: np.ndarray, offset: int, channel_id: int) -> np.ndarray:
    """``(n, 2)`` int64 ``(log_time, offset)`` of the ``MessageIndex`` record at ``offset``."""
    n = _index_count(buf, offset, channel_id)
    start = offset + _IDX_HEAD
    entries = np.frombuffer(buf[start : start + 16 * n].tobytes(), dtype="<u8")
    return entries.astype(np.int64).reshape(-1, 2)


def _index_count(buf: np.ndarray, offset: int, channel_id: int) -> int:
    """The number of entries of the ``MessageIndex`` record at ``offset`` (its head checked
    as :func:`message_index` checks it; the entries are not read)."""
    from mcap.opcode import Opcode

    head = bytes(buf[offset : offset + _IDX_HEAD])
    if len(head) < _IDX_HEAD or head[0] != Opcode.MESSAGE_INDEX:
        raise layout.LayoutError("the chunk index points at no message index record")
    length = int.from_bytes(head[1:9], "little")
    cid = int.from_bytes(head[9:11], "little")
    nbytes = int.from_bytes(head[11:15], "little")
    if cid != channel_id or nbytes % 16 or length != 2 + 4 + nbytes:
        raise layout.LayoutError("message index record of another channel or size")
    if offset + _IDX_HEAD + nbytes > len(buf):
        raise layout.LayoutError("message index beyond the end of the file")
    return nbytes // 16


def locate(buf: np.ndarray, summary: Any, wanted: dict[int, int]) -> list[Located]:
    """The chunks (file order) holding a channel of ``wanted`` (``{channel id: label}``)
    and where their message indexes are; ``LayoutError`` when the summary cannot say (the
    message counts the index records declare are checked against the statistics here,
    before any message is read)."""
    chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    if not chunks:
        raise layout.LayoutError("MCAP file without chunk indexes")
    counts = {cid: 0 for cid in wanted}
    out = []
    for number, ch in enumerate(chunks, 1):
        if not ch.message_index_offsets:
            raise layout.LayoutError("a chunk without message indexes")
        present = [cid for cid in wanted if cid in ch.message_index_offsets]
        if not present:
            continue
        if ch.compression not in _COMPRESSIONS:
            raise layout.LayoutError(f"chunk compression {ch.compression!r}")
        for cid in present:
            counts[cid] += _index_count(buf, ch.message_index_offsets[cid], cid)
        indexes = tuple((cid, wanted[cid], ch.message_index_offsets[cid]) for cid in present)
        out.append(Located(ch, indexes, number))
    stats = summary.statistics.channel_message_counts if summary.statistics else {}
    for cid, n in counts.items():
        if cid in stats and int(stats[cid]) != n:
            raise layout.LayoutError("message indexes disagree with the statistics")
    return out


def _records(
    buf: np.ndarray, rec: np.ndarray, channel: np.ndarray, log_ns: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(starts, ends) of the message data of the records at ``rec`` (their byte positions in
    ``buf``), each checked against the index: op code ``MESSAGE``, channel id, log time.

    A ``Message`` record is ``uint8 opcode, uint64 length, uint16 channel_id, uint32
    sequence, uint64 log_time, uint64 publish_time``, then the data up to ``9 + length``.
    """
    from mcap.opcode import Opcode

    if len(rec) == 0:
        return rec, rec
    if rec.max() + _MSG_HEAD > len(buf):
        raise layout.LayoutError("message record beyond the chunk")
    # every record's fixed head in one copy (one pass over the scattered records, not four)
    head = layout._words(buf, rec, _MSG_HEAD, "u1")
    if not np.all(head[:, 0] == Opcode.MESSAGE):
        raise layout.LayoutError("the index points at a record that is not a message")
    if not np.array_equal(layout.column(head, 9, "<u2"), channel):
        raise layout.LayoutError("message record of another channel than the index says")
    if not np.array_equal(layout.column(head, 15, "<u8").view(np.int64), log_ns):
        raise layout.LayoutError("message log time differs from the index")
    length = layout.column(head, 1, "<u8").astype(np.int64)
    starts = rec + _MSG_HEAD
    ends = rec + 9 + length
    if length.min() < _MSG_HEAD - 9 or ends.max() > len(buf):
        raise layout.LayoutError("message data beyond the chunk")
    return starts, ends


def _batch(buf: np.ndarray, base: list[int], locs: list[Located], file: np.ndarray) -> Batch:
    """One batch over ``buf``, chunk ``k``'s records starting at byte ``base[k]`` (``file``:
    the whole file, where the message indexes are)."""
    rows = [loc.rows(file) for loc in locs]
    rec = np.concatenate([b + r[0] for b, r in zip(base, rows, strict=True)])
    log_ns = np.concatenate([r[1] for r in rows])
    channel = np.concatenate([r[2] for r in rows])
    starts, ends = _records(buf, rec, channel, log_ns)
    return Batch(buf, starts, ends, log_ns, np.concatenate([r[3] for r in rows]))


def _data_start(buf: np.ndarray, ch: Any) -> int:
    """Where an uncompressed chunk's records start in the file: the data is the chunk
    record's last field, preceded by its ``uint64`` length (checked)."""
    start = ch.chunk_start_offset + ch.chunk_length - ch.compressed_size
    if ch.compressed_size != ch.uncompressed_size or start < 8 or start > len(buf):
        raise layout.LayoutError("uncompressed chunk whose sizes disagree")
    if int(layout._words(buf, np.array([start - 8]), 1, "<u8")[0, 0]) != ch.compressed_size:
        raise layout.LayoutError("chunk data is not where the chunk index says")
    return int(start)


_CRC_AT = 1 + 8 + 8 + 8 + 8  # opcode, length, start time, end time, uncompressed size


def check_crc(path: Path, loc: Located, data: Any, stored: int) -> None:
    """Refuse a chunk whose uncompressed records ``data`` do not match their ``stored`` CRC
    (0: the writer stored none)."""
    if stored == 0:
        return
    computed = zlib.crc32(data)
    if computed != stored:
        raise InputError(
            f"{path}: MCAP chunk {loc.number} (at byte {loc.chunk.chunk_start_offset}) fails "
            f"its CRC check (stored {stored:08x}, computed {computed:08x}): its data was "
            "changed or damaged; copy the file again from the recording, or salvage the "
            "intact chunks ('mcap recover IN.mcap -o OUT.mcap') and try again"
        )


def _check_mapped_crc(path: Path, buf: np.ndarray, loc: Located, start: int) -> None:
    """The CRC of an uncompressed chunk read through the memory map."""
    at = loc.chunk.chunk_start_offset + _CRC_AT
    if at + 4 > len(buf):
        raise layout.LayoutError("chunk record beyond the end of the file")
    stored = int.from_bytes(bytes(buf[at : at + 4]), "little")
    check_crc(path, loc, buf[start : start + loc.chunk.uncompressed_size], stored)


def _decompressed(fh: Any, ch: Any, path: Path | None = None, loc: Located | None = None) -> bytes:
    """The records of one chunk, decompressed once with the ``mcap`` package's helpers
    (checked against the chunk's CRC when ``loc`` is given)."""
    from mcap.data_stream import ReadDataStream
    from mcap.exceptions import UnsupportedCompressionError
    from mcap.records import Chunk
    from mcap.stream_reader import get_chunk_data_stream

    fh.seek(ch.chunk_start_offset + 1 + 8)
    chunk = Chunk.read(ReadDataStream(fh))
    try:
        stream, size = get_chunk_data_stream(chunk)
    except UnsupportedCompressionError as exc:
        raise layout.LayoutError(f"cannot decompress {exc}") from None
    data = stream.read(size)
    if len(data) != ch.uncompressed_size:
        raise layout.LayoutError(
            f"chunk at byte {ch.chunk_start_offset} decompressed to another size than its index says"
        )
    if path is not None and loc is not None:
        check_crc(path, loc, data, chunk.uncompressed_crc)
    return data


def mcap_batches(path: Path, summary: Any, wanted: dict[int, int]) -> Iterator[Batch]:
    """The messages of the channels in ``wanted`` (``{channel id: label}``; ``Batch.conn``
    holds the label), chunk by chunk in file order (module docstring), in batches of about
    ``_BATCH_BYTES``: memory stays bounded whatever the file's length.

    All chunks uncompressed: one batch per window of consecutive chunks, read through a
    memory map of the file (only the pages holding wanted records are read; a window's
    pages leave the resident set when the next batch is asked for: the map's views are
    dropped). Otherwise the chunks are decompressed once each and copied into batches in
    one reused buffer (fresh memory per batch costs more in page faults than the
    decompression): a batch's ``buf`` is only valid until the next batch is asked for.
    Raises :class:`layout.LayoutError` (before yielding) when the summary cannot locate the
    messages, or later when a record is not where the index says.
    """
    import mmap

    with open(path, "rb") as fh:
        if fh.seek(0, 2) == 0:
            raise layout.LayoutError("empty MCAP file")
        mm = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
    try:
        yield from _mcap_batches(path, mm, summary, wanted)
    finally:
        # release the pages read (and the map once nothing views it any more)
        with contextlib.suppress(BufferError):
            mm.close()


def _release(mm: Any, lo: int, hi: int) -> None:
    """Drop the pages of ``mm[lo:hi]`` from the resident set (read again from the file if
    touched again): ``madvise(MADV_DONTNEED)`` where the platform has it."""
    import mmap

    advice = getattr(mmap, "MADV_DONTNEED", None)
    if advice is None:
        return
    lo -= lo % mmap.PAGESIZE
    if hi > lo:
        mm.madvise(advice, lo, min(hi, len(mm)) - lo)


def _mcap_batches(path: Path, mm: Any, summary: Any, wanted: dict[int, int]) -> Iterator[Batch]:
    # a plain ndarray over the map: memmap's __getitem__ costs more than the gathers
    buf = np.frombuffer(mm, dtype=np.uint8)
    locs = locate(buf, summary, wanted)
    if not locs:
        return
    if all(loc.chunk.compression == "" for loc in locs):
        k = 0
        while k < len(locs):
            window = [locs[k]]
            lo = window[0].chunk.chunk_start_offset
            k += 1
            while k < len(locs):
                ch = locs[k].chunk
                if ch.chunk_start_offset + ch.chunk_length - lo > _BATCH_BYTES:
                    break
                window.append(locs[k])
                k += 1
            starts = [_data_start(buf, loc.chunk) for loc in window]
            for loc, start in zip(window, starts, strict=True):
                _check_mapped_crc(path, buf, loc, start)
            yield _batch(buf, starts, window, buf)
            last = window[-1].chunk
            _release(mm, lo, last.chunk_start_offset + last.chunk_length)
        return
    # at most one batch up front; grown from the data actually decompressed, never from the
    # index's (unverified) sizes alone
    sizes = sum(loc.chunk.uncompressed_size for loc in locs)
    work = np.empty(min(_BATCH_BYTES, max(sizes, 0)), np.uint8)
    base: list[int] = []
    group: list[Located] = []
    size = 0
    with open(path, "rb") as fh:
        for loc in locs:
            data = _decompressed(fh, loc.chunk, path, loc)
            if group and size + len(data) > _BATCH_BYTES:
                yield _batch(work[:size], base, group, buf)
                _release(mm, 0, loc.chunk.chunk_start_offset)  # the indexes read so far
                base, group, size = [], [], 0
            if size + len(data) > len(work):
                grown = np.empty(max(size + len(data), min(2 * len(work), _BATCH_BYTES)), np.uint8)
                grown[:size] = work[:size]
                work = grown
            work[size : size + len(data)] = np.frombuffer(data, np.uint8)
            base.append(size)
            group.append(loc)
            size += len(data)
    if group:
        yield _batch(work[:size], base, group, buf)


def topic_batches(
    files: list[Path], infos: list[TopicInfo], summary: Any = None
) -> Iterator[Batch]:
    """The messages of ``infos`` in every MCAP file (plain, or a rosbag2's storage files),
    labelled by their index in ``infos``; ``summary``: the one file's summary when already
    read. ``LayoutError`` when a channel is not CDR of the topic's type."""
    label = {info.topic: k for k, info in enumerate(infos)}
    for f in files:
        s = summary if summary is not None else read_summary(f)
        wanted = {}
        for cid, ch in s.channels.items():
            if ch.topic not in label:
                continue
            schema = s.schemas.get(ch.schema_id)
            mt = normalize_type(schema.name) if schema else "?"
            if ch.message_encoding != "cdr" or mt != infos[label[ch.topic]].msgtype:
                raise layout.LayoutError(f"channel {ch.topic} is not cdr {mt}")
            wanted[cid] = label[ch.topic]
        yield from mcap_batches(f, s, wanted)
