"""Readers: the numpy fast paths against rosbags' and mcap's per-message deserializers."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from qsls.pipeline.ingest.sources import layout
from qsls.pipeline.ingest.sources.bags import BagSource
from qsls.pipeline.ingest.sources.base import detect
from qsls.pipeline.ingest.sources.messages import ImageStream, PoseStream
from qsls.pipeline.ingest.sources.msgtypes import ODOMETRY, POSE_COV, POSE_STAMPED, TRANSFORM
from qsls.pipeline.ingest.sources.ros1.index import ros1_batches
from qsls.pipeline.ingest.sources.text.reader import read_euroc, read_tum
from qsls.pipeline.ingest.sources.write import FORMATS, write_bag
from tests.bagfixtures import T0_NS, make_flight, tf_streams


def ros1_slices(
    reader1: Any, conn_ids: set[int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """All messages of ``conn_ids`` in one buffer, in time order: ``(buf, starts, ends, log_ns)``.

    It copies every message; readers use :func:`ros1_batches`.
    """
    pieces: list[tuple[int, bytes]] = []
    for b in ros1_batches(reader1, conn_ids):
        for s, e, t in zip(b.starts.tolist(), b.ends.tolist(), b.log_ns.tolist(), strict=True):
            pieces.append((t, bytes(b.buf[s:e])))
    pieces.sort(key=lambda x: x[0])
    buf, starts, ends = layout.concat([p for _, p in pieces])
    return buf, starts, ends, np.array([t for t, _ in pieces], dtype=np.int64)


TYPES = (POSE_STAMPED, POSE_COV, TRANSFORM, ODOMETRY)


def _streams(n: int = 300) -> list:
    f = make_flight(duration=n / 50.0, dropouts=())
    t = f.truth
    out = [f.vio]
    for k, mt in enumerate(TYPES):
        # odd-length frame names exercise CDR alignment after strings
        out.append(
            PoseStream(f"/p{k}", t.header_ns[:n], t.log_ns[:n] + k, t.position[:n], t.orientation[:n],
                       msgtype=mt, frame_id="w" * (k + 1), child_frame_id="c" * (2 * k + 1))
        )  # fmt: skip
    ts = np.asarray(f.vio.log_ns[::25]) + 3
    out.append(ImageStream("/cam", ts, ts, height=24, width=32))
    return out


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("read")
    s = _streams()
    out = {
        fmt: write_bag(d / f"b_{fmt}{'.bag' if fmt == 'ros1' else ''}", s, fmt) for fmt in FORMATS
    }
    out["ros1-lz4"] = write_bag(d / "lz4.bag", s, "ros1", compression="lz4", chunk_size=20_000)
    out["ros2-zstd"] = write_bag(d / "z", s, "ros2-sqlite", compression="zstd")
    out["mcap-zstd"] = write_bag(d / "z.mcap", s, "mcap", compression="zstd")
    return out


@pytest.mark.parametrize("key", [*FORMATS, "ros1-lz4", "ros2-zstd", "mcap-zstd"])
def test_fast_decoding_equals_deserializer(bags: dict[str, Path], key: str) -> None:
    with BagSource(bags[key]) as src:
        topics = {t.topic: t for t in src.topics()}
        assert topics["/cam"].msgtype == "sensor_msgs/msg/Image"
        for name in ["/vio/odom", "/p0", "/p1", "/p2", "/p3"]:
            fast = src.read(name)
            slow = src.read(name, fast=False)
            assert fast.decoder == "numpy"
            assert slow.decoder == "deserializer"
            assert len(fast) == topics[name].count == 300
            for attr in ("header_ns", "log_ns", "position", "orientation"):
                np.testing.assert_array_equal(
                    getattr(fast, attr), getattr(slow, attr), err_msg=attr
                )
            assert (fast.frame_id, fast.child_frame_id) == (slow.frame_id, slow.child_frame_id)
            if topics[name].msgtype == ODOMETRY:
                np.testing.assert_array_equal(fast.velocity, slow.velocity)
            else:
                assert fast.velocity is None
        odo = src.read("/vio/odom")
        s = _streams()[0]
        np.testing.assert_array_equal(odo.header_ns, s.header_ns)
        np.testing.assert_array_equal(odo.position, s.position)
        np.testing.assert_array_equal(odo.velocity, s.linear_velocity)


@pytest.mark.parametrize(("key", "batch"), [("ros1", None), ("ros1-lz4", None), ("ros1-lz4", 2000)])
def test_ros1_index_slices_are_rosbags_bytes(
    bags: dict[str, Path], key: str, batch: int | None, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The chunk slicing at rosbags' index offsets gives rosbags' raw messages, byte for byte."""
    from rosbags.rosbag1 import Reader

    from qsls.pipeline.ingest.sources.ros1 import index as bagmod

    if batch:  # many small batches through the reused decompression buffer
        monkeypatch.setattr(bagmod, "_BATCH_BYTES", batch)
        with BagSource(bags[key]) as src:
            fast, slow = (
                src.read_many([("/vio/odom", None), ("/p1", None)]),
                [src.read("/vio/odom", fast=False), src.read("/p1", fast=False)],
            )
            for f, s in zip(fast, slow, strict=True):
                assert f.decoder == "numpy"
                np.testing.assert_array_equal(f.position, s.position)
                np.testing.assert_array_equal(f.log_ns, s.log_ns)

    with Reader(bags[key]) as r:
        for topic in ("/vio/odom", "/p2", "/cam"):
            conns = [c for c in r.connections if c.topic == topic]
            if key == "ros1-lz4":
                assert len(r.chunk_infos) > 10
            buf, starts, ends, logs = ros1_slices(r, {c.id for c in conns})
            ref = list(r.messages(connections=conns))
            assert len(ref) == len(starts) > 0
            for k, (_c, log, raw) in enumerate(ref):
                assert bytes(buf[starts[k] : ends[k]]) == raw
                assert logs[k] == log


def test_tf_topic_needs_frame(tmp_path: Path) -> None:
    f = make_flight(duration=2.0, dropouts=())
    t = f.truth
    a, b = tf_streams(t, "cam", t.position + 5, 1)
    for fmt in ("ros1", "mcap"):
        bag = write_bag(tmp_path / f"tf.{'bag' if fmt == 'ros1' else 'mcap'}", [a, b], fmt)
        with BagSource(bag) as src:
            got = src.read("/tf", truth_frame="/world/quad")
            np.testing.assert_array_equal(got.position, t.position)
            np.testing.assert_array_equal(got.header_ns, t.header_ns)
            from qsls.pipeline.core.errors import InputError

            with pytest.raises(InputError, match=r"quad/cam \(400\)"):
                src.read("/tf")


def test_lone_storage_files(bags: dict[str, Path], tmp_path: Path) -> None:
    """A rosbag2 storage file alone (no metadata.yaml beside it) still reads."""
    import shutil

    db = next(bags["ros2-sqlite"].glob("*.db3"))
    lone = shutil.copy(db, tmp_path / "lone.db3")
    mc = shutil.copy(next(bags["ros2-mcap"].glob("*.mcap")), tmp_path / "lone.mcap")
    assert detect(Path(lone)) == "db3"
    assert detect(Path(mc)) == "mcap"
    assert detect(db) == "rosbag2"
    for p in (lone, mc, db):
        with BagSource(Path(p)) as src:
            odo = src.read("/vio/odom")
            assert len(odo) == 300 and odo.header_ns[0] == T0_NS


def test_text_formats(tmp_path: Path) -> None:
    tum = tmp_path / "a.txt"
    tum.write_text(
        "# t x y z qx qy qz qw\n1403715273.262142 1 2 3 0 0 0 1\n1403715273.3 4 5 6 0 0 1 0\n"
    )
    t = read_tum(tum)
    assert detect(tum) == "tum"
    assert t.header_ns.tolist() == [1403715273262142000, 1403715273300000000]
    assert t.position[1].tolist() == [4, 5, 6]
    csv = tmp_path / "g.csv"
    csv.write_text(
        "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], v_x, v_y, v_z\n"
        "1403715523912143104,1,2,3,0.5,0.1,0.2,0.3,7,8,9\n"
    )
    e = read_euroc(csv)
    assert detect(csv) == "euroc"
    assert e.header_ns[0] == 1403715523912143104  # exact: not through float
    assert e.orientation[0].tolist() == [0.1, 0.2, 0.3, 0.5]
    assert e.velocity[0].tolist() == [7, 8, 9]


def test_sqlite_bulk_rows_are_rosbags_messages(bags: dict[str, Path]) -> None:
    """The one-query-per-topic read of a sqlite3 rosbag2 gives rosbags' messages, stamp and byte
    for byte, in order; a compressed bag is left to rosbags."""
    from rosbags.rosbag2 import Reader

    from qsls.pipeline.core.progress import NULL_PROGRESS

    bag = bags["ros2-sqlite"]
    (db,) = bag.glob("*.db3")
    with BagSource(bag) as src:
        assert src.reader.storage() == ("sqlite3", [db])
        infos = [i for i in src.topics() if i.topic in ("/vio/odom", "/p1")]
        got = src._raw_pass(infos, NULL_PROGRESS)
    with Reader(bag) as r:
        for topic in ("/vio/odom", "/p1"):
            conns = [c for c in r.connections if c.topic == topic]
            want = [(log, bytes(raw)) for _, log, raw in r.messages(connections=conns)]
            raws, logs, _ = got[topic]
            assert len(want) > 100 and list(zip(logs, raws, strict=True)) == want
    with BagSource(bags["ros2-zstd"]) as src:
        assert src.reader.storage() is None


def test_sqlite_bag_read_without_opening_rosbags(bags: dict[str, Path]) -> None:
    """An uncompressed sqlite3 rosbag2 is listed from its metadata.yaml and its pose topics
    read with one SQL query: rosbags' reader (which scans the whole database on opening) is
    never opened, and the result is rosbags' deserializer's; a compressed bag goes through
    rosbags."""
    with BagSource(bags["ros2-sqlite"]) as src:
        listed = {t.topic: (t.msgtype, t.count) for t in src.topics()}
        fast = src.read_many([("/vio/odom", None), ("/p0", None)])
        assert not src.reader.rosbags_opened
    with BagSource(bags["ros2-sqlite"]) as src:
        slow = src.read_many([("/vio/odom", None), ("/p0", None)], fast=False)
        assert src.reader.rosbags_opened  # opened for the deserializer
    with BagSource(bags["ros1"]) as ros1:
        assert listed == {t.topic: (t.msgtype, t.count) for t in ros1.topics()}
    for f, s in zip(fast, slow, strict=True):
        assert (f.decoder, s.decoder) == ("numpy", "deserializer")
        assert len(f) > 100 and np.array_equal(f.header_ns, s.header_ns)
        assert np.array_equal(f.log_ns, s.log_ns) and np.array_equal(f.position, s.position)
        assert np.array_equal(f.orientation, s.orientation) and f.frame_id == s.frame_id
    with BagSource(bags["ros2-zstd"]) as src:
        assert src.reader.rosbags_opened and src.read("/vio/odom").decoder == "numpy"
