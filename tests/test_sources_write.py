"""write_bag: every format round-trips through the official readers (rosbags, mcap)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from qsls.pipeline.ingest.sources.messages import OdometryStream, PoseStream
from qsls.pipeline.ingest.sources.msgtypes import TF, TRANSFORM
from qsls.pipeline.ingest.sources.write import FORMATS, write_bag


def _streams(n: int = 50) -> list:
    rng = np.random.default_rng(1)
    t = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 20_000_000
    p = rng.normal(size=(n, 3))
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    v = rng.normal(size=(n, 3))
    return [
        OdometryStream("/vio/odom", t, t + 5_000_000, p, q, v),
        PoseStream("/mocap/pose", t + 3, t + 1_000_000, p + 1, q),
        PoseStream(
            "/tf", t + 7, t + 2_000_000, p + 2, q, msgtype=TF, frame_id="w", child_frame_id="b"
        ),
        PoseStream("/tr", t, t, p - 1, q, msgtype=TRANSFORM),
    ]


def _read_rosbags(path: Path) -> dict[str, list]:
    from rosbags.highlevel import AnyReader

    out: dict[str, list] = {}
    with AnyReader([path]) as r:
        for conn, log, raw in r.messages():
            out.setdefault(conn.topic, []).append((log, r.deserialize(raw, conn.msgtype)))
    return out


def _read_mcap(path: Path) -> dict[str, list]:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out: dict[str, list] = {}
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        for _schema, channel, message, msg in reader.iter_decoded_messages():
            out.setdefault(channel.topic, []).append((message.log_time, msg))
    return out


@pytest.mark.parametrize("fmt", FORMATS)
def test_round_trip(tmp_path: Path, fmt: str) -> None:
    streams = _streams()
    path = write_bag(tmp_path / ("b.bag" if fmt == "ros1" else f"b_{fmt}"), streams, fmt)
    assert path.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp left
    msgs = _read_mcap(path) if fmt == "mcap" else _read_rosbags(path)
    odo, pose, tf, tr = streams
    assert sorted(msgs) == sorted(s.topic for s in streams)
    got = msgs["/vio/odom"]
    assert [log for log, _ in got] == list(odo.log_ns)
    m = got[7][1]
    st = m.header.stamp
    assert st.sec * 10**9 + st.nanosec == odo.header_ns[7]
    assert m.child_frame_id == "base_link"
    p = m.pose.pose.position
    assert (p.x, p.y, p.z) == tuple(odo.position[7])
    q = m.pose.pose.orientation
    assert (q.x, q.y, q.z, q.w) == tuple(odo.orientation[7])
    v = m.twist.twist.linear
    assert (v.x, v.y, v.z) == tuple(odo.linear_velocity[7])
    pm = msgs["/mocap/pose"][3][1]
    assert pm.pose.position.x == pose.position[3, 0]
    assert pm.header.stamp.nanosec == pose.header_ns[3] % 10**9
    tm = msgs["/tf"][4][1].transforms[0]
    assert (tm.header.frame_id, tm.child_frame_id) == ("w", "b")
    assert tm.transform.translation.z == tf.position[4, 2]
    assert msgs["/tr"][2][1].transform.rotation.w == tr.orientation[2, 3]
    # messages come out in log-time order across topics
    logs = sorted((log, topic) for topic, v in msgs.items() for log, _ in v)
    assert len(logs) == 4 * len(odo)


@pytest.mark.parametrize(
    ("fmt", "comp"),
    [
        ("ros1", "lz4"),
        ("ros1", "bz2"),
        ("ros2-mcap", "zstd"),
        ("ros2-sqlite", "zstd"),
        ("mcap", "lz4"),
    ],
)
def test_compressed(tmp_path: Path, fmt: str, comp: str) -> None:
    streams = _streams(20)
    path = write_bag(tmp_path / ("c.bag" if fmt == "ros1" else "c"), streams, fmt, compression=comp)
    msgs = _read_mcap(path) if fmt == "mcap" else _read_rosbags(path)
    assert len(msgs["/mocap/pose"]) == 20


def test_bad_arguments_leave_nothing(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown bag format"):
        write_bag(tmp_path / "x", _streams(3), "ros3")
    with pytest.raises(ValueError, match="compression"):
        write_bag(tmp_path / "x", _streams(3), "ros1", compression="zstd")
    s = _streams(3)[0]
    bad = OdometryStream(
        s.topic, s.header_ns, s.log_ns, s.position[:2], s.orientation, s.linear_velocity
    )
    with pytest.raises(ValueError, match="shape"):
        write_bag(tmp_path / "x", [bad], "ros1")
    assert list(tmp_path.iterdir()) == []
