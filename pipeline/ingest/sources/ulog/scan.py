"""A ULog's messages walked once, so that pyulog parses only what is asked for.

A ULog is a 16-byte header and then messages ``uint16 size, uint8 type, payload`` back to
back, with no index and no end marker. pyulog (:func:`load`) goes through every message in
Python, about 0.7 µs each, even those of the topics its filter drops: on a vehicle's log,
the odometry ingest reads is a small part of the messages. :func:`walk` steps through
the framing alone (the size and type of each message, about 0.2 µs each, reading the file
in blocks of :data:`BLOCK` bytes) and keeps the header, every message that is not data,
and the data messages (``D``) of the topics asked for; pyulog then parses that stream,
which holds all it would have kept of the file (formats, subscriptions, parameters and
their changes, info, dropouts, logged strings, the topics' data, in the file's order): the
same result as its filtered read of the file, for a fraction of the time and memory.

The walk also tells a file cut inside a message (the last message runs past the end: a
copy or a recording cut short), which pyulog reads without a word: such a file is refused.
A file whose framing the walk does not follow (a message type it does not know, a size of
0, data of a topic never subscribed, appended data) goes to pyulog whole
(:func:`load_whole`), with an info message appended after its last byte
(:class:`_WithTail`): pyulog parses that message only if every message before it was whole,
and marks what it finds garbled (``file_corruption``); both are refused too.
"""

from __future__ import annotations

import contextlib
import io
import mmap
import os
import struct
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from qsls.pipeline.core.errors import InputError
from qsls.pipeline.ingest.sources.ulog.writer import MAGIC

BLOCK = 1 << 22
"""Bytes read at once by :func:`walk` (its memory besides what it keeps)."""

HEADER = 16
_KNOWN = frozenset(b"BFIMPQARDLCOS")
"""The message types of ULog format version 1 (a type outside them: :func:`load_whole`)."""
_D, _A, _B, _F, _O = (ord(c) for c in "DABFO")
_U64 = struct.Struct("<Q")
_HEAD = struct.Struct("<HBH")
"""A message's size and type, and a data message's ``msg_id``."""

_END_KEY = "_qsls_reader_end_of_file"


def _info_message(key: str, value: bytes) -> bytes:
    """A ULog info message ``I``: ``key`` a ``char[len]`` string."""
    k = f"char[{len(value)}] {key}".encode()
    return struct.pack("<HB", 1 + len(k) + len(value), ord("I")) + bytes([len(k)]) + k + value


_END_MESSAGE = _info_message(_END_KEY, b"ok")
"""An info message appended after the file's last byte (:class:`_WithTail`)."""


@dataclass
class Walk:
    """What :func:`walk` found: the stream for pyulog, and facts of the whole file."""

    kept: mmap.mmap
    """The header, every message but data, and the data of the topics asked for, as a
    readable file-like map (at its start)."""
    subscriptions: dict[int, tuple[str, int]] = field(default_factory=dict)
    """``msg_id -> (topic, instance)`` of every subscription."""
    counts: dict[int, int] = field(default_factory=dict)
    """Data messages per ``msg_id``."""
    last_us: int = 0
    """The largest data timestamp (``stamps``), at least the header's start."""
    dropouts: list[tuple[int, int]] = field(default_factory=list)
    """``(timestamp_us, ms)`` of each dropout, its stamp the largest before it (``stamps``)."""


def damaged(path: Path, what: str) -> InputError:
    return InputError(
        f"{path}: the ULog is {what}; copy the log again from the vehicle's SD card (a log cut "
        "off by a power loss or a full card cannot be read as a whole)"
    )


def _check_magic(path: Path) -> None:
    if not path.is_file():
        raise InputError(f"{path}: no such file; check the path")
    with open(path, "rb") as fh:
        if fh.read(len(MAGIC)) != MAGIC:
            raise InputError(f"{path}: not a PX4 ULog (no ULog header); give a .ulg log")


def walk(path: Path, topics: Sequence[str], *, stamps: bool = False) -> Walk | None:
    """The messages of ``path`` pyulog needs for ``topics`` (module docstring), or None when
    the file must go to pyulog whole (:func:`load_whole`). ``stamps`` (a listing): count the
    data messages of every subscription and follow their timestamps (``last_us``, the
    dropouts' stamps; every subscribed format must start with ``uint64_t timestamp``, as
    PX4's do, else None). A one-line :class:`InputError` when the file ends inside a
    message."""
    path = Path(path)
    _check_magic(path)
    # what is kept goes to an anonymous map as large as the file, of which only the pages
    # written are ever resident; pyulog reads it as a file (no copy of it is made)
    kept = mmap.mmap(-1, max(path.stat().st_size, HEADER))
    try:
        found = _walk(path, set(topics), stamps, kept)
    except BaseException:
        kept.close()
        raise
    if found is None:
        kept.close()
    return found


def _walk(path: Path, wanted: set[str], stamps: bool, kept: mmap.mmap) -> Walk | None:
    """:func:`walk` into ``kept``."""
    keep: dict[int, bool] = {}  # msg_id -> its data kept (a subscription's id: known)
    get = keep.get
    counts: dict[int, int] = {}
    subs: dict[int, tuple[str, int]] = {}
    stamped: dict[str, bool] = {}  # format -> its first field is uint64_t timestamp
    out = kept.write
    dropouts: list[tuple[int, int]] = []
    head5 = _HEAD.unpack_from
    u64 = _U64.unpack_from
    with open(path, "rb") as fh:
        head = fh.read(HEADER)
        out(head)
        last = u64(head, 8)[0]
        rest = b""
        while True:
            block = fh.read(BLOCK)
            if not block:
                break
            buf = rest + block if rest else block
            view = memoryview(buf)  # slices of it are copied once, into ``kept``
            pos, n = 0, len(buf)
            while pos + 5 <= n:  # size, type and (for data) msg_id
                size, kind, msg_id = head5(buf, pos)
                end = pos + 3 + size
                if end > n:
                    break
                if kind == _D:  # the bulk of a log: as few steps as can be
                    k = get(msg_id)
                    if k:
                        out(view[pos:end])
                    elif k is None:
                        return None  # data of no subscription (or before it)
                    if stamps:
                        counts[msg_id] = counts.get(msg_id, 0) + 1
                        if size >= 10 and (ts := u64(buf, pos + 5)[0]) > last:
                            last = ts
                    pos = end
                    continue
                if size == 0 or kind not in _KNOWN:
                    return None
                if kind == _A:
                    if size < 3:
                        return None
                    multi_id, msg_id = buf[pos + 3], buf[pos + 4] | (buf[pos + 5] << 8)
                    name = buf[pos + 6 : end].split(b"\0", 1)[0].decode("utf-8", "replace")
                    subs[msg_id] = (name, multi_id)
                    keep[msg_id] = name in wanted
                    if stamps and not stamped.get(name, False):
                        return None
                elif kind == _F and stamps:
                    text = buf[pos + 3 : end].decode("utf-8", "replace")
                    name, _, fields = text.partition(":")
                    stamped[name] = fields.split(";", 1)[0].strip() == "uint64_t timestamp"
                elif (kind == _B and _appended(buf[pos + 3 : end])) or (kind == _O and size < 2):
                    return None  # offsets into the file (appended data), a dropout cut short
                elif kind == _O and stamps:
                    dropouts.append((last, buf[pos + 3] | (buf[pos + 4] << 8)))
                out(view[pos:end])
                pos = end
            rest = buf[pos:]
            view.release()
    if rest:  # a message cut by the end of the file (or one of under 3 bytes: not ULog's)
        if len(rest) >= 3 and 3 + (rest[0] | rest[1] << 8) == len(rest):
            return None
        raise damaged(path, "truncated (it ends inside a message)")
    kept.resize(kept.tell())
    kept.seek(0)
    return Walk(kept, subs, counts, last, dropouts)


def _appended(flags: bytes) -> bool:
    """A flag-bits payload that declares appended data (offsets into the file: whole)."""
    if len(flags) < 40:
        return False
    offsets = struct.unpack_from("<3Q", flags, 16)
    return bool(flags[8] & 1) and any(offsets)


def parse(source: Any, path: Path, topics: Sequence[str] | None, header_only: bool) -> Any:
    """pyulog on ``source`` (a path or a readable binary object, ``path`` naming it), its
    errors one line."""
    from pyulog import ULog

    try:
        with contextlib.redirect_stdout(io.StringIO()):  # pyulog prints its warnings
            u = ULog(source, message_name_filter_list=topics, parse_header_only=header_only)
    except InputError:
        raise
    except Exception as exc:  # pyulog's own, or what a garbled file makes it raise
        what = (
            "a message's size points before the file's start"
            if isinstance(exc, OSError)
            else " ".join(str(exc).split()) or type(exc).__name__
        )
        raise damaged(path, f"damaged ({what})") from None
    if u.file_corruption:
        raise damaged(path, "damaged (pyulog found corrupt messages in it)")
    return u


def load(path: Path, topics: Sequence[str], *, header_only: bool = False) -> Any:
    """``pyulog.ULog`` of ``path`` with only ``topics``' data (pyulog's
    ``message_name_filter_list``), read from :func:`walk`'s stream (or the whole file,
    :func:`load_whole`); ``header_only``: the definitions alone (formats, info,
    parameters). A one-line :class:`InputError` for a file that is not a ULog, is damaged or
    ends inside a message (module docstring)."""
    path = Path(path)
    if header_only:
        _check_magic(path)
        return parse(str(path), path, list(topics), True)
    found = walk(path, topics)
    if found is None:
        return load_whole(path, topics)
    return parse(found.kept, path, list(topics), False)


def load_whole(path: Path, topics: Sequence[str] | None) -> Any:
    """pyulog over the whole file with :data:`_END_MESSAGE` after it (:class:`_WithTail`);
    ``topics`` None: every topic buffered."""
    path = Path(path)
    _check_magic(path)
    stream = io.BufferedReader(_WithTail(path, _END_MESSAGE), buffer_size=1 << 20)
    try:
        u = parse(stream, path, None if topics is None else list(topics), False)
    finally:
        stream.close()
    if _END_KEY not in u.msg_info_dict:
        raise damaged(path, "truncated (it ends inside a message)")
    u.msg_info_dict.pop(_END_KEY, None)
    return u


class _WithTail(io.RawIOBase):
    """The file's bytes, then ``tail``: what pyulog is given to read in :func:`load_whole`.

    pyulog stops without a word at a message cut short by the end of the file. With an
    info message appended, a whole file ends with that message parsed; a cut one swallows
    it into the cut message (or misreads it), so its absence says the file was cut."""

    def __init__(self, path: Path, tail: bytes) -> None:
        super().__init__()
        self._file = open(path, "rb", buffering=0)  # noqa: SIM115 (closed by close())
        self._size = os.fstat(self._file.fileno()).st_size
        self._tail = tail
        self._pos = 0

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def readinto(self, buffer: Any) -> int:
        view = memoryview(buffer).cast("B")
        if self._pos < self._size:
            self._file.seek(self._pos)
            n = self._file.readinto(view[: self._size - self._pos]) or 0
        else:
            k = self._pos - self._size
            chunk = self._tail[k : k + len(view)]
            view[: len(chunk)] = chunk
            n = len(chunk)
        self._pos += n
        return n

    def seek(self, offset: int, whence: int = 0) -> int:
        pos = {0: 0, 1: self._pos, 2: self._size + len(self._tail)}[whence] + offset
        if pos < 0:  # as a file does (pyulog seeks back by a garbled size)
            raise OSError(22, "Invalid argument")
        self._pos = pos
        return pos

    def tell(self) -> int:
        return self._pos

    def close(self) -> None:
        self._file.close()
        super().close()
