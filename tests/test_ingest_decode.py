"""The numpy field reader against rosbags' deserializer where message lengths vary.

A topic whose messages all have one length and lie back to back (a rosbag2 sqlite3 topic,
read in one query) is read through one strided view; a topic whose frame names change
length from message to message, or messages scattered between other records (ROS1, MCAP),
through one gathered copy per message. Both must give what rosbags' (or mcap's)
per-message deserializer gives, field for field.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from qsls.pipeline.ingest.sources import layout
from qsls.pipeline.ingest.sources.bags import BagSource
from qsls.pipeline.ingest.sources.messages import PoseStream
from qsls.pipeline.ingest.sources.msgtypes import POSE_STAMPED
from qsls.pipeline.ingest.sources.write import FORMATS, write_bag
from tests.bagfixtures import make_flight

# (frame_id, child_frame_id) per interleaved part of /vio/odom: an empty name, a long one,
# and two pairs of the same total length whose second string starts at different offsets
# (CDR pads each string's length word to 4 bytes)
ODOM_FRAMES = [
    ("odom", "base_link"),
    ("", "b"),
    ("w" * 61, "imu_0"),
    ("ab", "cdef"),
    ("abcd", "ef"),
]
POSE_FRAMES = ["world", "a_13_chars_xy", "v"]


def _split(stream, frames):
    """``stream`` as interleaved parts (message ``i`` in part ``i % len(frames)``), one frame
    pair each: written to one topic they give messages of varying length."""
    parts = []
    for k, fr in enumerate(frames):
        i = np.arange(k, len(stream), len(frames))
        kw = {"header_ns": stream.header_ns[i], "log_ns": stream.log_ns[i],
              "position": stream.position[i], "orientation": stream.orientation[i]}  # fmt: skip
        if isinstance(fr, tuple):
            kw |= {"frame_id": fr[0], "child_frame_id": fr[1],
                   "linear_velocity": stream.linear_velocity[i], "angular_velocity": None}  # fmt: skip
        else:
            kw["frame_id"] = fr
        parts.append(replace(stream, **kw))
    return parts


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("decode")
    f = make_flight(duration=6.0, vio_hz=50, truth_hz=100, dropouts=())
    t = f.truth
    odd = PoseStream("/odd", t.header_ns, t.log_ns + 7, t.position, t.orientation,
                     msgtype=POSE_STAMPED, frame_id="x" * 13)  # fmt: skip
    streams = [*_split(f.vio, ODOM_FRAMES), *_split(f.truth, POSE_FRAMES), odd]
    names = {"ros1": "b.bag", "mcap": "b.mcap"}
    return {fmt: write_bag(d / names.get(fmt, f"b_{fmt}"), streams, fmt) for fmt in FORMATS}


@pytest.mark.parametrize("fmt", FORMATS)
def test_varying_lengths_decode_as_the_deserializer(bags: dict[str, Path], fmt: str) -> None:
    with BagSource(bags[fmt]) as src:
        names = ["/vio/odom", "/mocap/pose", "/odd"]
        fast = src.read_many([(n, None) for n in names])
        slow = src.read_many([(n, None) for n in names], fast=False)
    for name, a, b in zip(names, fast, slow, strict=True):
        assert (a.decoder, b.decoder) == ("numpy", "deserializer"), name
        assert len(a) == len(b) > 250
        for attr in ("header_ns", "log_ns", "position", "orientation"):
            np.testing.assert_array_equal(getattr(a, attr), getattr(b, attr), err_msg=attr)
        assert (a.frame_id, a.child_frame_id) == (b.frame_id, b.child_frame_id)
        if name == "/vio/odom":
            np.testing.assert_array_equal(a.velocity, b.velocity)
            assert (a.frame_id, a.child_frame_id) == ODOM_FRAMES[0]
        else:
            assert a.velocity is None
    assert fast[2].frame_id == "x" * 13


def test_sqlite_topic_back_to_back_in_one_buffer(bags: dict[str, Path]) -> None:
    """The sqlite3 read gives each topic's messages back to back: a topic of one length
    is equally spaced (the strided view), a topic of varying lengths is not."""
    from qsls.pipeline.ingest.sources.rosbag2.listing import open_rosbag2
    from qsls.pipeline.ingest.sources.rosbag2.sqlite import sqlite_batches

    bag = open_rosbag2(bags["ros2-sqlite"])
    assert bag is not None
    batches = {int(b.conn[0]): b for b in sqlite_batches(bag.files, ["/vio/odom", "/odd"])}
    for k, b in batches.items():
        assert np.array_equal(b.starts[1:], b.ends[:-1]) and b.starts[0] == 0
        assert b.ends[-1] == len(b.buf)
        lengths = set((b.ends - b.starts).tolist())
        assert len(lengths) == (1 if k == 1 else 4), lengths  # "ab"/"abcd" pairs: one length


def test_words_equal_slicing_and_own_their_memory() -> None:
    """``layout._words``: the words at equally spaced and at scattered byte positions are the
    bytes at those positions; the result is a copy (readers reuse their buffers), and a
    position outside the buffer is a LayoutError, not a read past its end."""
    rng = np.random.default_rng(7)
    buf = rng.integers(0, 256, size=5000, dtype=np.uint8)
    spaced = 13 + 37 * np.arange(100, dtype=np.int64)
    scattered = np.sort(rng.choice(4900, size=100, replace=False)).astype(np.int64)
    for pos in (spaced, scattered, spaced[:1]):
        for count, dtype in ((7, "<f8"), (2, "<u4"), (4, "u1")):
            got = layout._words(buf, pos, count, dtype)
            size = np.dtype(dtype).itemsize
            want = np.stack([buf[p : p + count * size].view(dtype) for p in pos.tolist()])
            assert got.shape == (len(pos), count) and got.flags.c_contiguous
            assert got.tobytes() == want.tobytes()
    work = buf.copy()
    got = layout._words(work, spaced, 2, "<u4")
    before = got.copy()
    work[:] = 0
    assert np.array_equal(got, before)
    one = layout._words(work, np.array([8]), 1, "<u8")  # a contiguous view would alias work
    work[8:16] = 255
    assert one[0, 0] == 0
    for bad in (np.array([4995]), np.array([-1, 10])):
        with pytest.raises(layout.LayoutError):
            layout._words(buf, bad, 1, "<u8")


@pytest.mark.parametrize("fmt", ["ros1", "ros2-sqlite", "ros2-mcap"])
def test_fast_paths_never_open_anyreader(bags: dict[str, Path], fmt: str) -> None:
    """ROS1 bags and uncompressed rosbag2 folders are listed and read without rosbags'
    AnyReader (its typestore and, for ROS1, its index of one object per message); the
    per-message deserializer opens it."""
    with BagSource(bags[fmt]) as src:
        counts = {t.topic: t.count for t in src.topics()}
        fast = src.read("/mocap/pose")
        assert not src.reader.rosbags_opened and fast.decoder == "numpy"
        assert src.read("/mocap/pose", fast=False).decoder == "deserializer"
        assert src.reader.rosbags_opened
        assert {t.topic: t.count for t in src.topics()} == counts
    assert counts["/mocap/pose"] == len(fast) and counts["/vio/odom"] > 250


def test_ros1_numpy_index_is_rosbags_index(bags: dict[str, Path]) -> None:
    """The ROS1 index read by numpy (ros1.index.open_ros1) has rosbags' entries: time, chunk,
    offset and connection of every message, in rosbags' order."""
    from rosbags.rosbag1 import Reader

    from qsls.pipeline.ingest.sources.ros1.index import _chunk_entries, _chunk_rows, open_ros1

    def index(reader: object, conns: set[int]) -> dict[int, np.ndarray]:
        return {pos: _chunk_rows(e) for pos, e in _chunk_entries(reader, conns).items()}

    fast = open_ros1(bags["ros1"])
    try:
        with Reader(bags["ros1"]) as r:
            for conns in ({c.id for c in r.connections}, {r.connections[0].id}):
                want, got = index(r, conns), index(fast, conns)
                assert sorted(want) == sorted(got)
                assert sum(len(w) for w in want.values()) > 250
                assert all(np.array_equal(got[k], want[k]) for k in want)
            assert fast.indexes == {c.id: [] for c in fast.connections}  # no objects built
    finally:
        fast.close()


@pytest.fixture(scope="module")
def uniform_sqlite(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A sqlite3 bag whose /vio/odom (Odometry) and /mocap/pose topics each keep one layout,
    and a /swap Odometry topic alternating frame pairs of one total length whose second
    string and pose lie at different offsets."""
    f = make_flight(duration=6.0, vio_hz=50, truth_hz=100, dropouts=())
    swap = [replace(s, topic="/swap") for s in _split(f.vio, [("ab", "cdef"), ("abcd", "ef")])]
    # /long: a short first message, then messages 2 kB longer
    t = replace(f.truth, topic="/long")
    long = [_part(t, slice(0, 1), frame_id="w"), _part(t, slice(1, None), frame_id="x" * 2000)]
    d = tmp_path_factory.mktemp("uniform")
    return write_bag(d / "u", [f.vio, f.truth, *swap, *long], "ros2-sqlite")


def _part(stream, rows: slice, **fields):
    keep = ("header_ns", "log_ns", "position", "orientation")
    return replace(stream, **{k: getattr(stream, k)[rows] for k in keep}, **fields)


def _sqlite(bag: Path, topics: list[str], msgtypes: list[str] | None) -> dict[int, list]:
    from qsls.pipeline.ingest.sources.rosbag2.listing import open_rosbag2
    from qsls.pipeline.ingest.sources.rosbag2.sqlite import sqlite_batches

    listed = open_rosbag2(bag)
    assert listed is not None
    out: dict[int, list] = {}
    for b in sqlite_batches(listed.files, topics, msgtypes):
        out.setdefault(int(b.conn[0]), []).append(b)
    return out


def test_sqlite_trimmed_records_hold_the_fields(uniform_sqlite: Path) -> None:
    """A topic of one layout comes as trimmed records (an Odometry message without its two
    covariances, all zero here: 148 of its 724 bytes), decoded as rosbags' deserializer decodes the whole
    messages; /swap's messages have one length but not one layout (their fixed bytes
    differ), so it comes whole, and decodes the same."""
    from qsls.pipeline.ingest.sources.msgtypes import ODOMETRY

    topics = ["/vio/odom", "/mocap/pose", "/swap"]
    whole = _sqlite(uniform_sqlite, topics, None)
    trimmed = _sqlite(uniform_sqlite, topics, [ODOMETRY, POSE_STAMPED, ODOMETRY])
    lengths = {k: set((b.ends - b.starts).tolist()) for k, (b,) in whole.items()}
    assert len(lengths[2]) == 1  # one length, two layouts
    assert [b.trimmed for (b,) in trimmed.values()] == ["lean", "lean", False]
    odom = trimmed[0][0]
    (full,) = lengths[0]
    assert set((odom.ends - odom.starts).tolist()) == {full - 2 * 36 * 8}
    for k in (0, 1):
        np.testing.assert_array_equal(trimmed[k][0].log_ns, whole[k][0].log_ns)
    with BagSource(uniform_sqlite) as src:
        fast = src.read_many([(t, None) for t in topics])
        slow = src.read_many([(t, None) for t in topics], fast=False)
    for a, b in zip(fast, slow, strict=True):
        assert (a.decoder, b.decoder) == ("numpy", "deserializer") and len(a) > 250
        for attr in ("header_ns", "log_ns", "position", "orientation", "velocity"):
            np.testing.assert_array_equal(getattr(a, attr), getattr(b, attr), err_msg=attr)
        assert (a.frame_id, a.child_frame_id) == (b.frame_id, b.child_frame_id)


def test_sqlite_trimmed_read_in_ranges_under_the_length_limit(
    uniform_sqlite: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Under a small SQLite length limit each query covers a range of row ids whose result
    stays within half the limit: many batches, together the same records and times; a
    topic whose later messages are longer than its first is read row by row there."""
    import sqlite3

    from qsls.pipeline.ingest.sources.msgtypes import ODOMETRY
    from qsls.pipeline.ingest.sources.rosbag2 import sqlite as sq

    topics, types = ["/vio/odom", "/mocap/pose"], [ODOMETRY, POSE_STAMPED]
    one = _sqlite(uniform_sqlite, topics, types)
    connect = sq._connect

    def small(db: Path) -> sqlite3.Connection:
        con = connect(db)
        con.setlimit(sqlite3.SQLITE_LIMIT_LENGTH, 20_000)
        return con

    monkeypatch.setattr(sq, "_connect", small)
    # messages longer than the first one, whose ranges SQLite refuses to concatenate under
    # the limit: fetched row by row, decoded as the deserializer decodes them
    (long,) = _sqlite(uniform_sqlite, ["/long"], [POSE_STAMPED]).values()
    assert len(long) > 1 and not any(b.trimmed for b in long)
    with BagSource(uniform_sqlite) as src:
        fast, slow = src.read("/long"), src.read("/long", fast=False)
    assert fast.decoder == "numpy" and len(fast) == len(slow) > 500
    for attr in ("header_ns", "log_ns", "position", "orientation"):
        np.testing.assert_array_equal(getattr(fast, attr), getattr(slow, attr), err_msg=attr)
    many = _sqlite(uniform_sqlite, topics, types)
    for k in (0, 1):
        assert len(one[k]) == 1 and len(many[k]) > 10 and all(b.trimmed for b in many[k])
        assert max(len(b.buf) for b in many[k]) <= 10_000
        assert b"".join(b.buf.tobytes() for b in many[k]) == one[k][0].buf.tobytes()
        np.testing.assert_array_equal(np.concatenate([b.log_ns for b in many[k]]), one[k][0].log_ns)


@pytest.mark.parametrize("ros1", [True, False], ids=["ros1", "cdr"])
def test_plan_trim_keeps_every_field_of_every_fixed_type(ros1: bool) -> None:
    """Each fixed-layout type, in both encodings, trims to a record of the message without
    its skipped blocks whose fields are the message's: its stamp and position as written."""
    from qsls.pipeline.ingest.sources.messages import MessageBuilder
    from qsls.pipeline.ingest.sources.msgtypes import ODOMETRY, POSE_TYPES, TF

    f = make_flight(duration=1.0, vio_hz=20, truth_hz=20, dropouts=())
    b = MessageBuilder(ros1)
    for mt in (t for t in POSE_TYPES if t != TF):
        s = f.vio if mt == ODOMETRY else replace(f.truth, msgtype=mt, frame_id="map_13_chars")
        raw = b.serialize(b.message(s, 3), mt)
        enc = "ros1" if ros1 else "cdr"
        trim = layout.plan_trim(raw, mt, enc)
        skipped = 8 * sum(op[2] for op in layout._PROGRAMS[mt] if op[0] == "f64" and op[1] is None)
        assert trim.length == len(raw) and trim.size <= len(raw) - skipped, mt
        assert trim.record == b"".join(raw[a:b] for a, b in trim.spans) and trim.spans[0][0] == 0
        whole = layout.decode(np.frombuffer(raw, np.uint8), [0], [len(raw)], mt, enc)
        rec = np.frombuffer(trim.record, np.uint8)
        cut = layout.decode(rec, [0], [trim.size], mt, enc, trimmed=True)
        assert (cut.frame_id, cut.child_frame_id) == (whole.frame_id, whole.child_frame_id)
        assert cut.header_ns[0] == whole.header_ns[0] == s.header_ns[3], mt
        np.testing.assert_array_equal(cut.pose, whole.pose, err_msg=mt)
        np.testing.assert_array_equal(cut.pose[0, :3], s.position[3], err_msg=mt)
        if mt == ODOMETRY:
            np.testing.assert_array_equal(cut.twist, whole.twist)


def test_plan_trim_refuses_a_cut_that_would_move_a_field(monkeypatch: pytest.MonkeyPatch) -> None:
    """A skipped block after a string leaves the string's padding in the record, where the
    next string, aligned to 4 only, would be read from the wrong place: refused."""
    import struct

    prog = (("time",), ("str", "frame_id"), ("f64", None, 1), ("str", "child_frame_id"),
            ("f64", "pose", 7))  # fmt: skip
    monkeypatch.setitem(layout._PROGRAMS, "test/Cut", prog)
    monkeypatch.setitem(layout._TRIMMED, "test/Cut", tuple(op for op in prog if op[1:2] != (None,)))
    body = (
        struct.pack("<iII", 5, 6, 5) + b"abcd\0" + bytes(7)  # stamp, "abcd", padding to 24
        + struct.pack("<d", 9.0) + struct.pack("<I", 2) + b"b\0" + bytes(2)  # skipped; "b"
        + struct.pack("<7d", *range(7))  # pose at 40
    )  # fmt: skip
    raw = b"\0\1\0\0" + body
    whole = layout.decode(np.frombuffer(raw, np.uint8), np.array([0]), np.array([len(raw)]),
                          "test/Cut", "cdr")  # fmt: skip
    assert whole.child_frame_id == "b" and whole.pose[0, 6] == 6.0
    with pytest.raises(layout.LayoutError):
        layout.plan_trim(raw, "test/Cut", "cdr")
