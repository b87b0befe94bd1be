"""Write a PX4 ULog file (format version 1) from numpy columns.

The file layout is PX4's (docs.px4.io, "ULog File Format"): a 16-byte header (``ULog``
magic, version, start time in µs), a flag-bits message, then the definitions (one format
message ``F`` per topic, info ``I`` and parameter ``P`` messages), the subscriptions ``A``
and the data section: ``D`` messages of all topics in timestamp order, with dropout ``O``
messages where the logger lost data. Every message is ``uint16 size, uint8 type, payload``,
little endian, packed.

The data section is built with numpy: each topic's samples are one packed structured array
(message header, msg_id, fields), viewed as bytes and scattered into the file in the
merged timestamp order, so a log of millions of messages is written at memory speed.
(pyulog's own ``write_ulog`` packs field by field in Python; it reads what this writes.)
"""

from __future__ import annotations

import os
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from qsls.pipeline.core.locks import make_temporary

MAGIC = b"ULog\x01\x12\x35"
VERSION = 1

_TYPES = {
    "int8_t": "<i1", "uint8_t": "<u1", "int16_t": "<i2", "uint16_t": "<u2",
    "int32_t": "<i4", "uint32_t": "<u4", "int64_t": "<i8", "uint64_t": "<u8",
    "float": "<f4", "double": "<f8", "bool": "<u1", "char": "<u1",
}  # fmt: skip
"""ULog's field types and their numpy dtypes."""


@dataclass(frozen=True)
class Topic:
    """One logged topic instance: ``fields`` as ``(type, name)`` in message order (``float[3]
    position`` is ``("float[3]", "position")``; the first must be ``uint64_t timestamp``),
    ``data`` the columns by field name (an array field ``(n, k)``), ``multi_id`` the
    instance."""

    name: str
    fields: Sequence[tuple[str, str]]
    data: Mapping[str, np.ndarray]
    multi_id: int = 0


@dataclass(frozen=True)
class LogContent:
    """What goes in one ULog: topics, parameters (int or float), info strings, dropouts
    ``(timestamp µs, duration ms)``."""

    topics: Sequence[Topic]
    parameters: Mapping[str, int | float] = field(default_factory=dict)
    info: Mapping[str, str] = field(default_factory=dict)
    dropouts: Sequence[tuple[int, int]] = ()
    start_us: int = 0


def _message(kind: bytes, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), kind[0]) + payload


def _field_dtype(type_str: str) -> tuple[str, tuple[int, ...]]:
    base, _, rest = type_str.partition("[")
    if base not in _TYPES:
        raise ValueError(f"unknown ULog field type {type_str!r}")
    return _TYPES[base], ((int(rest.rstrip("]")),) if rest else ())


def _info(key_type: str, key: str, value: bytes) -> bytes:
    k = f"{key_type} {key}".encode()
    return struct.pack("<B", len(k)) + k + value


def _parameter(name: str, value: int | float) -> bytes:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"parameter {name}: {value!r} is not an int or a float")
    if isinstance(value, int):
        return _info("int32_t", name, struct.pack("<i", value))
    return _info("float", name, struct.pack("<f", value))


def _records(topic: Topic, msg_id: int) -> tuple[np.ndarray, np.ndarray]:
    """``(timestamps (n,), records (n, size) uint8)`` of one topic's ``D`` messages."""
    names = [n for _, n in topic.fields]
    if not names or names[0] != "timestamp":
        raise ValueError(f"{topic.name}: the first field must be 'uint64_t timestamp'")
    dt = np.dtype(
        [("size", "<u2"), ("type", "<u1"), ("msg_id", "<u2")]
        + [(n, *_field_dtype(t)) for t, n in topic.fields]
    )
    n = len(np.asarray(topic.data["timestamp"]))
    rec = np.zeros(n, dtype=dt)
    rec["size"] = dt.itemsize - 3
    rec["type"] = ord("D")
    rec["msg_id"] = msg_id
    for _, name in topic.fields:
        if name in topic.data:
            rec[name] = np.asarray(topic.data[name]).reshape(rec[name].shape)
    return rec["timestamp"].astype(np.uint64), rec.view(np.uint8).reshape(n, dt.itemsize)


def ulog_bytes(content: LogContent) -> bytes:
    """The whole file (module docstring)."""
    head = MAGIC + bytes([VERSION]) + struct.pack("<Q", content.start_us)
    flags = _message(b"B", bytes(16) + struct.pack("<3Q", 0, 0, 0))
    defs = []
    for name in dict.fromkeys(t.name for t in content.topics):
        t = next(t for t in content.topics if t.name == name)
        fmt = name + ":" + "".join(f"{ty} {n};" for ty, n in t.fields)
        defs.append(_message(b"F", fmt.encode()))
    for k, v in content.info.items():
        b = v.encode()
        defs.append(_message(b"I", _info(f"char[{len(b)}]", k, b)))
    for k, p in content.parameters.items():
        defs.append(_message(b"P", _parameter(k, p)))
    subs, stamps, blocks = [], [], []
    for msg_id, t in enumerate(content.topics):
        subs.append(_message(b"A", struct.pack("<BH", t.multi_id, msg_id) + t.name.encode()))
        ts, rec = _records(t, msg_id)
        stamps.append(ts)
        blocks.append(rec)
    for ts_us, ms in content.dropouts:
        stamps.append(np.array([ts_us], dtype=np.uint64))
        blocks.append(np.frombuffer(_message(b"O", struct.pack("<H", ms)), np.uint8)[None, :])
    data = _merged(stamps, blocks)
    return head + flags + b"".join(defs) + b"".join(subs) + data


def _merged(stamps: list[np.ndarray], blocks: list[np.ndarray]) -> bytes:
    """The records of every block in one stable timestamp order, as bytes."""
    if not blocks:
        return b""
    ts = np.concatenate(stamps)
    which = np.concatenate([np.full(len(s), i) for i, s in enumerate(stamps)])
    row = np.concatenate([np.arange(len(s)) for s in stamps])
    order = np.argsort(ts, kind="stable")
    sizes = np.array([b.shape[1] for b in blocks])[which[order]]
    start = np.zeros(len(order), dtype=np.int64)
    np.cumsum(sizes[:-1], out=start[1:])
    out = np.empty(int(sizes.sum()), dtype=np.uint8)
    pos = np.empty(len(order), dtype=np.int64)
    pos[order] = start
    for i, b in enumerate(blocks):
        sel = which == i
        idx = pos[sel][:, None] + np.arange(b.shape[1])
        out[idx] = b[row[sel]]
    return out.tobytes()


def write_ulog(path: Path, content: LogContent) -> Path:
    """Write ``content`` to ``path`` atomically (a temporary name, then a rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    folder = make_temporary(path)
    tmp = folder / path.name
    try:
        tmp.write_bytes(ulog_bytes(content))
        os.replace(tmp, path)
    finally:
        if folder.exists():
            import shutil

            shutil.rmtree(folder, ignore_errors=True)
    return path
