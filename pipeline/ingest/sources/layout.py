"""Decode a whole topic of fixed-layout messages at once with numpy.

The pose messages qsls reads have a layout that is fixed up to their strings: a header
(``seq`` in ROS1, the stamp, ``frame_id``), maybe ``child_frame_id``, then blocks of
float64. Given one byte buffer and the start and end of every message's serialized data
in it (as rosbags' or mcap's readers hand them out), the fields of all messages are
gathered with vectorized index arithmetic instead of one Python deserializer call per
message.

Encodings:

- ``ros1``: little-endian, no alignment; header ``uint32 seq``, ``uint32 sec, nsec``;
  strings are ``uint32 length`` + bytes.
- ``cdr``: a 4-byte encapsulation header (``00 01 00 00``: CDR, little-endian), then the
  body with every primitive aligned to its size relative to the body start; stamp
  ``int32 sec, uint32 nanosec``; strings ``uint32 length`` (including the NUL) + bytes.

Every message is checked to end where its data ends (CDR: up to 3 padding bytes), so a
layout that is not what the message type says raises :class:`LayoutError` and the caller
falls back to rosbags' deserializer. A test compares every field against that
deserializer.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qsls.pipeline.ingest.sources.write import ODOMETRY, POSE_COV, POSE_STAMPED, TRANSFORM


class LayoutError(ValueError):
    """The bytes do not have the fixed layout of the message type."""


# Field programs. ("time",) stamp; ("str", name) string; ("f64", name, count) doubles
# (name None: skipped). Every pose-like type has 7 contiguous doubles: x y z qx qy qz qw.
_PROGRAMS: dict[str, tuple[tuple, ...]] = {
    ODOMETRY: (
        ("time",),
        ("str", "frame_id"),
        ("str", "child_frame_id"),
        ("f64", "pose", 7),
        ("f64", None, 36),
        ("f64", "twist", 6),
        ("f64", None, 36),
    ),
    POSE_STAMPED: (("time",), ("str", "frame_id"), ("f64", "pose", 7)),
    POSE_COV: (("time",), ("str", "frame_id"), ("f64", "pose", 7), ("f64", None, 36)),
    TRANSFORM: (("time",), ("str", "frame_id"), ("str", "child_frame_id"), ("f64", "pose", 7)),
}

FIXED_TYPES = tuple(_PROGRAMS)


@dataclass(frozen=True)
class Decoded:
    """Fields of ``n`` messages: stamps, 7-double pose, optional twist and frame names."""

    header_ns: np.ndarray  # int64 (n,)
    pose: np.ndarray  # (n, 7): x y z qx qy qz qw
    twist: np.ndarray | None  # (n, 6): linear, angular (Odometry only)
    frame_id: str
    child_frame_id: str


def _words(buf: np.ndarray, pos: np.ndarray, count: int, dtype: str) -> np.ndarray:
    """``count`` little-endian words of ``dtype`` starting at byte ``pos[i]`` of ``buf`` (1-D
    ``uint8``), for every ``i``: a contiguous ``(n, count)`` array; :class:`LayoutError` if
    one leaves ``buf``.

    The ``count`` words of a message are one opaque item of an array over ``buf`` itself
    whose items start ``step`` bytes apart: ``step`` the spacing of equally spaced positions
    (the messages of a topic stored back to back, all of one length: a rosbag2 sqlite3
    topic read in one query), copied at once; else 1, an item starting at every byte, of
    which ``pos`` picks one per message. One copy per message, no index per byte or word.
    """
    dt = np.dtype(dtype)
    n, nbytes = len(pos), count * dt.itemsize
    if n == 0:
        return np.zeros((0, count), dt)
    if int(pos.min()) < 0 or int(pos.max()) + nbytes > len(buf):
        raise LayoutError("a field beyond the end of the data")
    p0 = int(pos[0])
    step = int(pos[1] - p0) if n > 1 else 1
    item = np.dtype((np.void, nbytes))  # one copy per message, not per word or byte
    if step > 0 and np.array_equal(pos, p0 + step * np.arange(n, dtype=np.int64)):
        # a copy even when the view is contiguous: callers reuse their buffers
        raw = np.array(np.ndarray((n,), item, buffer=buf, offset=p0, strides=(step,)))
    else:
        raw = np.ndarray((len(buf) - nbytes + 1,), item, buffer=buf, strides=(1,))[pos]
    return raw.view(dt).reshape(n, count)


def column(rows: np.ndarray, at: int, dtype: str) -> np.ndarray:
    """The little-endian word of ``dtype`` at byte ``at`` of every row of ``rows`` (``(n, k)``
    ``uint8``, e.g. record heads gathered at once by :func:`_words`): ``(n,)``."""
    size = np.dtype(dtype).itemsize
    return np.ascontiguousarray(rows[:, at : at + size]).view(dtype)[:, 0]


def _u32(buf: np.ndarray, pos: np.ndarray) -> np.ndarray:
    return _words(buf, pos, 1, "<u4")[:, 0].astype(np.int64)


def _string0(buf: np.ndarray, pos: int, length: int, cdr: bool) -> str:
    raw = bytes(buf[pos : pos + length])
    if cdr and raw.endswith(b"\0"):
        raw = raw[:-1]
    return raw.decode("utf-8", errors="replace")


def decode(
    buf: np.ndarray, starts: np.ndarray, ends: np.ndarray, msgtype: str, encoding: str
) -> Decoded:
    """Decode messages ``buf[starts[i]:ends[i]]`` of ``msgtype`` (``ros1`` or ``cdr``)."""
    program = _PROGRAMS.get(msgtype)
    if program is None:
        raise LayoutError(f"{msgtype} has no fixed layout")
    if encoding not in ("ros1", "cdr"):
        raise LayoutError(f"unknown encoding {encoding!r}")
    buf = np.asarray(buf)
    if buf.dtype != np.uint8:
        buf = buf.view(np.uint8)
    starts = np.asarray(starts, dtype=np.int64)
    ends = np.asarray(ends, dtype=np.int64)
    n = len(starts)
    cdr = encoding == "cdr"
    size = len(buf)
    if n == 0:
        return Decoded(np.zeros(0, np.int64), np.zeros((0, 7)), None, "", "")
    if ends.max() > size or (ends - starts).min() < 8:
        raise LayoutError("message bounds outside the buffer or too short")
    if cdr:
        enc = _words(buf, starts, 4, "u1")
        if not (np.all(enc[:, 0] == 0) and np.all(enc[:, 1] == 1)):
            raise LayoutError("not little-endian plain CDR")
        base = starts + 4
        pos = base.copy()
    else:
        base = starts
        pos = starts + 4  # seq

    out: dict[str, np.ndarray] = {}
    names: dict[str, str] = {}
    header_ns = np.zeros(n, np.int64)
    for op in program:
        if np.any(pos > ends):
            raise LayoutError("field beyond the end of a message")
        if op[0] == "time":
            if cdr:
                pos = base + ((pos - base + 3) & ~3)
            t = _words(buf, pos, 2, "<u4").astype(np.int64)
            sec = t[:, 0] - ((t[:, 0] >> 31) << 32) if cdr else t[:, 0]  # int32 in CDR
            nsec = t[:, 1]
            header_ns = sec * 1_000_000_000 + nsec
            pos = pos + 8
        elif op[0] == "str":
            if cdr:
                pos = base + ((pos - base + 3) & ~3)
            if np.any(pos + 4 > ends):
                raise LayoutError("string length beyond the end of a message")
            length = _u32(buf, pos)
            if cdr and length.min() < 1:
                raise LayoutError("CDR string without terminator")
            names[op[1]] = _string0(buf, int(pos[0]) + 4, int(length[0]), cdr)
            pos = pos + 4 + length
        else:
            count = op[2]
            if cdr:
                pos = base + ((pos - base + 7) & ~7)
            if np.any(pos + 8 * count > ends):
                raise LayoutError("float block beyond the end of a message")
            if op[1] is not None:
                out[op[1]] = _words(buf, pos, count, "<f8")
            pos = pos + 8 * count
    slack = ends - pos
    if slack.min() < 0 or slack.max() > (3 if cdr else 0):
        raise LayoutError("message length does not match the type's layout")
    return Decoded(
        header_ns=header_ns,
        pose=out["pose"],
        twist=out.get("twist"),
        frame_id=names.get("frame_id", ""),
        child_frame_id=names.get("child_frame_id", ""),
    )


def concat(chunks: list[bytes]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One buffer and the start/end offsets of a list of raw messages."""
    lengths = np.fromiter((len(c) for c in chunks), dtype=np.int64, count=len(chunks))
    ends = np.cumsum(lengths)
    starts = ends - lengths
    buf = np.frombuffer(b"".join(chunks), dtype=np.uint8)
    return buf, starts, ends
