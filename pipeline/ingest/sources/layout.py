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
deserializer. Trimmed records (:class:`Trim`, what the sqlite3 reader fetches) end after
their last field; for them that check is the reader's: every message as long as the one
the trim was planned on, which passed it.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from qsls.pipeline.ingest.sources.msgtypes import ODOMETRY, POSE_COV, POSE_STAMPED, TRANSFORM


class LayoutError(ValueError):
    """The bytes do not have the fixed layout of the message type."""


# Field programs. ("time",) stamp; ("str", name) string; ("f64", name, count) doubles
# (name None: skipped); ("cov", name) a row-major 6x6 covariance of doubles, of which the
# diagonal is read. Every pose-like type has 7 contiguous doubles: x y z qx qy qz qw.
_PROGRAMS: dict[str, tuple[tuple, ...]] = {
    ODOMETRY: (
        ("time",),
        ("str", "frame_id"),
        ("str", "child_frame_id"),
        ("f64", "pose", 7),
        ("cov", "pose_var"),
        ("f64", "twist", 6),
        ("cov", "twist_var"),
    ),
    POSE_STAMPED: (("time",), ("str", "frame_id"), ("f64", "pose", 7)),
    POSE_COV: (("time",), ("str", "frame_id"), ("f64", "pose", 7), ("f64", None, 36)),
    TRANSFORM: (("time",), ("str", "frame_id"), ("str", "child_frame_id"), ("f64", "pose", 7)),
}

COV_DIAG = 6
"""Doubles on a 6x6 covariance's diagonal, ``COV_STEP`` doubles apart (row-major)."""
COV_STEP = 7

# the programs of trimmed records (:class:`Trim`): the skipped blocks cut out, a covariance
# reduced to its diagonal
_TRIMMED = {
    k: tuple(
        ("f64", op[1], COV_DIAG) if op[0] == "cov" else op
        for op in p
        if op[0] != "f64" or op[1] is not None
    )
    for k, p in _PROGRAMS.items()
}

# the programs of lean trimmed records: the covariances cut out whole, as the skipped blocks
_LEAN = {
    k: tuple(op for op in p if op[0] != "cov" and (op[0] != "f64" or op[1] is not None))
    for k, p in _PROGRAMS.items()
}

FIXED_TYPES = tuple(_PROGRAMS)


@dataclass(frozen=True)
class Decoded:
    """Fields of ``n`` messages: stamps, 7-double pose, optional twist, frame names and
    (Odometry) the diagonals of the pose and twist covariances."""

    header_ns: np.ndarray  # int64 (n,)
    pose: np.ndarray  # (n, 7): x y z qx qy qz qw
    twist: np.ndarray | None  # (n, 6): linear, angular (Odometry only)
    frame_id: str
    child_frame_id: str
    pose_var: np.ndarray | None = None  # (n, 6): x y z, rotation about x y z (Odometry)
    twist_var: np.ndarray | None = None  # (n, 6): linear x y z, angular x y z (Odometry)


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


def _walk(
    buf: np.ndarray, starts: np.ndarray, ends: np.ndarray, program: tuple[tuple, ...], cdr: bool
) -> Iterator[tuple[tuple, np.ndarray, np.ndarray]]:
    """The fields of every message, in program order: ``(op, pos, end)`` with ``pos`` the
    field's aligned first byte and ``end`` one past its last (a string's from its length
    word), both ``(n,)``; last ``(("end",), pos, pos)`` after the final field. Raises
    :class:`LayoutError` when a field leaves its message."""
    base = starts + 4 if cdr else starts
    pos = base.copy() if cdr else starts + 4  # CDR: after the encapsulation; ROS1: seq
    for op in program:
        if np.any(pos > ends):
            raise LayoutError("field beyond the end of a message")
        if cdr:
            align = 7 if op[0] in ("f64", "cov") else 3
            pos = base + ((pos - base + align) & ~align)
        if op[0] == "time":
            end = pos + 8
        elif op[0] == "str":
            if np.any(pos + 4 > ends):
                raise LayoutError("string length beyond the end of a message")
            length = _u32(buf, pos)
            if cdr and length.min() < 1:
                raise LayoutError("CDR string without terminator")
            end = pos + 4 + length
        else:
            end = pos + 8 * (op[2] if op[0] == "f64" else COV_DIAG * COV_DIAG)
            if np.any(end > ends):
                raise LayoutError("float block beyond the end of a message")
        yield op, pos, end
        pos = end
    yield ("end",), pos, pos


def _check_encoding(buf: np.ndarray, starts: np.ndarray, encoding: str) -> bool:
    """True for CDR (whose 4-byte encapsulation must say plain little-endian CDR)."""
    if encoding not in ("ros1", "cdr"):
        raise LayoutError(f"unknown encoding {encoding!r}")
    if encoding == "ros1":
        return False
    enc = _words(buf, starts, 4, "u1")
    if not (np.all(enc[:, 0] == 0) and np.all(enc[:, 1] == 1)):
        raise LayoutError("not little-endian plain CDR")
    return True


def decode(
    buf: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
    msgtype: str,
    encoding: str,
    *,
    trimmed: bool | str = False,
) -> Decoded:
    """Decode messages ``buf[starts[i]:ends[i]]`` of ``msgtype`` (``ros1`` or ``cdr``);
    ``trimmed``: records cut by a :class:`Trim` (the skipped float blocks and whatever
    follows the last field read are not there; ``"lean"``: the covariances cut whole too)."""
    program = (_LEAN if trimmed == "lean" else _TRIMMED if trimmed else _PROGRAMS).get(msgtype)
    if program is None:
        raise LayoutError(f"{msgtype} has no fixed layout")
    buf = np.asarray(buf)
    if buf.dtype != np.uint8:
        buf = buf.view(np.uint8)
    starts = np.asarray(starts, dtype=np.int64)
    ends = np.asarray(ends, dtype=np.int64)
    n = len(starts)
    if n == 0:
        _check_encoding(buf, starts, encoding)
        return Decoded(np.zeros(0, np.int64), np.zeros((0, 7)), None, "", "")
    if ends.max() > len(buf) or (ends - starts).min() < 8:
        raise LayoutError("message bounds outside the buffer or too short")
    cdr = _check_encoding(buf, starts, encoding)
    out: dict[str, np.ndarray] = {}
    names: dict[str, str] = {}
    header_ns = np.zeros(n, np.int64)
    pos = starts
    for op, pos, end in _walk(buf, starts, ends, program, cdr):
        if op[0] == "time":
            t = _words(buf, pos, 2, "<u4").astype(np.int64)
            sec = t[:, 0] - ((t[:, 0] >> 31) << 32) if cdr else t[:, 0]  # int32 in CDR
            header_ns = sec * 1_000_000_000 + t[:, 1]
        elif op[0] == "str":
            names[op[1]] = _string0(buf, int(pos[0]) + 4, int(end[0] - pos[0]) - 4, cdr)
        elif op[0] == "f64" and op[1] is not None:
            out[op[1]] = _words(buf, pos, op[2], "<f8")
        elif op[0] == "cov":
            out[op[1]] = _diagonals(buf, pos)
    slack = ends - pos
    if slack.min() < 0 or slack.max() > (3 if cdr else 0):
        raise LayoutError("message length does not match the type's layout")
    return Decoded(
        header_ns=header_ns,
        pose=out["pose"],
        twist=out.get("twist"),
        frame_id=names.get("frame_id", ""),
        child_frame_id=names.get("child_frame_id", ""),
        pose_var=out.get("pose_var"),
        twist_var=out.get("twist_var"),
    )


def _diagonals(buf: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """The diagonal ``(n, 6)`` of the row-major 6x6 float64 matrix at byte ``pos[i]`` of
    ``buf``, for every ``i``: one gather through a view whose rows start at every byte and
    whose six items are ``8 * COV_STEP`` bytes apart."""
    span = 8 * (COV_STEP * (COV_DIAG - 1) + 1)
    n = len(pos)
    if n == 0:
        return np.zeros((0, COV_DIAG))
    if int(pos.min()) < 0 or int(pos.max()) + span > len(buf):
        raise LayoutError("a field beyond the end of the data")
    view = np.ndarray(
        (len(buf) - span + 1, COV_DIAG), np.dtype("<f8"), buffer=buf, strides=(1, 8 * COV_STEP)
    )
    return np.array(view[pos], dtype=float)


@dataclass(frozen=True)
class Trim:
    """What of a fixed-layout message a reader needs, planned on one message.

    ``spans`` are the message's byte ranges ``[a, b)`` a trimmed record keeps, in order:
    everything up to the last field read (an Odometry's twist covariance, else the pose)
    except the skipped float blocks (a PoseWithCovarianceStamped's covariance) and, of an
    Odometry's two covariances, all but their diagonals, so a trimmed record decodes with
    ``decode(..., trimmed=True)``: every cut starts 8-aligned and is a multiple of 8 long,
    so what follows it keeps its alignment; and in every program here it follows a float,
    so no padding before it is left in the record for the next field to misread (an
    Odometry message's 724 bytes become 244; 148 with ``lean``, the covariances cut whole). :func:`plan_trim` checks this on
    its message (the trimmed record decodes to the same fields).
    ``fixed`` are the record's byte ranges that every message of the same layout shares
    with this one: the encapsulation's identifier (CDR) and every string with its length
    word; a message whose ``fixed`` bytes and total ``length`` equal this one's has every
    field at this one's offsets, so its record holds exactly its fields. ``record`` is this
    message's own trimmed record, the reference for the ``fixed`` bytes.
    """

    spans: tuple[tuple[int, int], ...]
    fixed: tuple[tuple[int, int], ...]
    length: int
    record: bytes
    covariances: tuple[tuple[int, int], ...] = ()
    """The message's covariance blocks ``[a, b)`` (Odometry): cut whole from a lean trim."""
    lean: bool = False
    """The covariances are cut whole (records decode with ``trimmed="lean"``)."""

    @property
    def size(self) -> int:
        """A trimmed record's length."""
        return len(self.record)


def plan_trim(message: bytes, msgtype: str, encoding: str, *, lean: bool = False) -> Trim:
    """The :class:`Trim` of the messages laid out as ``message`` (``lean``: without the
    covariances, not even their diagonals): :class:`LayoutError` if it does not have
    ``msgtype``'s layout, or if its trimmed record would not decode to its fields."""
    buf = np.frombuffer(message, dtype=np.uint8)
    starts, ends = np.zeros(1, np.int64), np.full(1, len(buf), np.int64)
    whole = decode(buf, starts, ends, msgtype, encoding)
    cdr = encoding == "cdr"
    cuts: list[tuple[int, int]] = []  # message byte ranges left out, in order
    strings: list[tuple[int, int]] = []
    blocks: list[tuple[int, int]] = []
    last = 0  # one past the last field read
    for op, pos, end in _walk(buf, starts, ends, _PROGRAMS[msgtype], cdr):
        a, b = int(pos[0]), int(end[0])
        if op[0] == "end":
            break
        if op[0] == "f64" and op[1] is None:  # skipped: cut out
            cuts.append((a, b))
            continue
        if op[0] == "cov":
            blocks.append((a, b))
            if lean:  # cut whole, as a skipped block
                cuts.append((a, b))
                continue
            # the diagonal kept, the 6 x 7 doubles between its items cut
            step = 8 * COV_STEP
            cuts += [(a + step * i + 8, a + step * (i + 1)) for i in range(COV_DIAG - 1)]
        elif op[0] == "str":
            strings.append((a, b))
        last = b
    spans: list[tuple[int, int]] = []
    kept = 0
    for a, b in cuts:
        spans.append((kept, a))
        kept = b
    spans.append((kept, last))
    spans = [(a, b) for a, b in spans if b > a]

    def in_record(x: int) -> int:  # a message offset inside a kept span, in the record
        return sum(min(b, x) - a for a, b in spans if a < x)

    fixed = [(0, 2)] if cdr else []  # ROS1's first word is the seq
    fixed += [(in_record(a), in_record(b)) for a, b in strings]
    record = b"".join(message[a:b] for a, b in spans)
    rec = np.frombuffer(record, dtype=np.uint8)
    kind = "lean" if lean else True
    cut = decode(rec, starts, np.full(1, len(rec), np.int64), msgtype, encoding, trimmed=kind)
    if lean:  # the covariances are not in it: compare the rest
        whole = Decoded(whole.header_ns, whole.pose, whole.twist, whole.frame_id,
                        whole.child_frame_id)  # fmt: skip
    if not _same(cut, whole):
        raise LayoutError(f"{msgtype}: its trimmed record does not hold its fields")
    return Trim(
        spans=tuple(spans), fixed=tuple(fixed), length=len(buf), record=record,
        covariances=tuple(blocks), lean=lean,
    )  # fmt: skip


def _same(a: Decoded, b: Decoded) -> bool:
    """Two decodings with the same fields, bit for bit."""
    arrays = [(a.header_ns, b.header_ns), (a.pose, b.pose)]
    for x, y in ((a.twist, b.twist), (a.pose_var, b.pose_var), (a.twist_var, b.twist_var)):
        if x is not None or y is not None:
            if x is None or y is None:
                return False
            arrays.append((x, y))
    return (a.frame_id, a.child_frame_id) == (b.frame_id, b.child_frame_id) and all(
        x.tobytes() == y.tobytes() for x, y in arrays
    )


def concat(chunks: list[bytes]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One buffer and the start/end offsets of a list of raw messages."""
    lengths = np.fromiter((len(c) for c in chunks), dtype=np.int64, count=len(chunks))
    ends = np.cumsum(lengths)
    starts = ends - lengths
    buf = np.frombuffer(b"".join(chunks), dtype=np.uint8)
    return buf, starts, ends


@dataclass(frozen=True)
class Batch:
    """Messages located in one buffer: message ``i`` is ``buf[starts[i]:ends[i]]``
    (``trimmed``: records cut by a :class:`Trim`, not whole messages; ``"lean"``:
    cut by a lean one, without the covariances)."""

    buf: np.ndarray
    starts: np.ndarray
    ends: np.ndarray
    log_ns: np.ndarray
    conn: np.ndarray
    trimmed: bool | str = False
