"""The MCAP whole-chunk decoder against the ``mcap`` package's reader + rosbags' deserializer.

Bags are written here with the official writers (``mcap.writer.Writer`` for plain MCAP,
``rosbags.rosbag2.Writer`` for rosbag2 MCAP storage), messages serialized by rosbags'
typestore, with frame_id strings whose lengths change from message to message (the CDR
alignment of the doubles after them moves), camera images interleaved in the same chunks,
zstd, lz4 and uncompressed chunks, and chunks small enough that a topic spans many chunks
or large enough that one chunk holds every channel.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.writer import IndexType

from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.progress import NULL_PROGRESS
from qsls.pipeline.ingest.sources import layout
from qsls.pipeline.ingest.sources.bags import BagSource
from qsls.pipeline.ingest.sources.mcap import chunks as mcapchunks
from qsls.pipeline.ingest.sources.msgtypes import (
    IMAGE,
    ODOMETRY,
    POSE_STAMPED,
    TRANSFORM,
    typestore,
)

N = 400  # messages per pose topic
TOPICS = {"/vio/odom": ODOMETRY, "/mocap/pose": POSE_STAMPED, "/tf_single": TRANSFORM}
T0 = 1_700_000_000_000_000_000


def _frame(k: int, i: int) -> str:
    """Frame names of 1..7 characters, changing every message (CDR padding changes too)."""
    return "f" * (1 + (3 * i + k) % 7)


def _message(ts: Any, topic: str, i: int) -> tuple[str, Any]:
    t = ts.types
    k = list(TOPICS).index(topic) if topic in TOPICS else 9
    sec, nsec = divmod(T0 + i * 5_000_000 + 137 * k, 1_000_000_000)
    hdr = t["std_msgs/msg/Header"](
        stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id=_frame(k, i)
    )
    v = np.sin(np.arange(13) + 0.1 * i + k)  # distinct doubles per message and field
    point = t["geometry_msgs/msg/Point"](x=v[0], y=v[1], z=v[2])
    vec3 = t["geometry_msgs/msg/Vector3"]
    quat = t["geometry_msgs/msg/Quaternion"](x=v[3], y=v[4], z=v[5], w=v[6])
    pose = t["geometry_msgs/msg/Pose"](position=point, orientation=quat)
    if topic == "/cam":
        img = (np.arange(32 * 24) * (i + 1) % 251).astype(np.uint8)
        return IMAGE, t[IMAGE](header=hdr, height=24, width=32, encoding="mono8",
                               is_bigendian=0, step=32, data=img)  # fmt: skip
    if TOPICS[topic] == POSE_STAMPED:
        return POSE_STAMPED, t[POSE_STAMPED](header=hdr, pose=pose)
    if TOPICS[topic] == TRANSFORM:
        tr = t["geometry_msgs/msg/Transform"](
            translation=vec3(x=v[0], y=v[1], z=v[2]), rotation=quat
        )
        return TRANSFORM, t[TRANSFORM](header=hdr, child_frame_id=_frame(k + 1, i), transform=tr)
    cov = np.linspace(0, 1, 36) * i
    twist = t["geometry_msgs/msg/Twist"](
        linear=vec3(x=v[7], y=v[8], z=v[9]), angular=vec3(x=v[10], y=v[11], z=v[12])
    )
    return ODOMETRY, t[ODOMETRY](
        header=hdr,
        child_frame_id=_frame(k + 2, i),
        pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=cov),
    )


def _schedule() -> list[tuple[int, str, int]]:
    """(log_ns, topic, i): pose topics at 200 Hz, interleaved, and a camera at 20 Hz."""
    rows = [(T0 + i * 5_000_000 + 11 * k, tp, i) for k, tp in enumerate(TOPICS) for i in range(N)]
    rows += [(T0 + i * 50_000_000 + 3, "/cam", i) for i in range(N // 10)]
    return sorted(rows)


def write_plain(path: Path, compression: str, chunk_size: int, **opts: Any) -> Path:
    from mcap.writer import CompressionType, Writer

    ts = typestore(ros1=False)
    with open(path, "wb") as fh:
        w = Writer(fh, compression=CompressionType[compression.upper()], chunk_size=chunk_size,
                   **opts)  # fmt: skip
        w.start(profile="ros2", library="qsls-test")
        chans = {}
        for tp, mt in [*TOPICS.items(), ("/cam", IMAGE)]:
            msgdef, _ = ts.generate_msgdef(mt, ros_version=2)
            sid = w.register_schema(name=mt, encoding="ros2msg", data=msgdef.encode())
            chans[tp] = w.register_channel(topic=tp, message_encoding="cdr", schema_id=sid)
        for log, tp, i in _schedule():
            mt, msg = _message(ts, tp, i)
            w.add_message(chans[tp], log_time=log, data=bytes(ts.serialize_cdr(msg, mt)),
                          publish_time=log, sequence=i)  # fmt: skip
        w.finish()
    return path


def write_rosbag2(
    path: Path, zstd_chunks: bool, rows: list[tuple[int, str, int]] | None = None, rev: bool = False
) -> Path:
    """A rosbag2 MCAP bag of ``rows`` (default: all), topics registered in reverse if ``rev``
    (other channel ids)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

    ts = typestore(ros1=False)
    w = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    if zstd_chunks:
        w.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    with w:
        topics = [*TOPICS.items(), ("/cam", IMAGE)]
        conns = {tp: w.add_connection(tp, mt, typestore=ts)
                 for tp, mt in (topics[::-1] if rev else topics)}  # fmt: skip
        for log, tp, i in _schedule() if rows is None else rows:
            mt, msg = _message(ts, tp, i)
            w.write(conns[tp], log, bytes(ts.serialize_cdr(msg, mt)))
    return path


def _mcap_file(bag: Path) -> Path:
    return bag if bag.is_file() else next(bag.glob("*.mcap"))


def reference(bag: Path, topic: str) -> dict[str, Any]:
    """Every decoded field of ``topic`` through ``mcap``'s reader + rosbags' deserializer."""
    from mcap.reader import make_reader

    ts = typestore(ros1=False)
    out: dict[str, list] = {"log": [], "header": [], "pose": [], "twist": [], "frame": [],
                            "data": []}  # fmt: skip
    with open(_mcap_file(bag), "rb") as fh:
        for schema, _, message in make_reader(fh).iter_messages(topics=[topic]):
            assert schema is not None
            msg = ts.deserialize_cdr(message.data, schema.name)
            out["log"].append(message.log_time)
            out["data"].append(bytes(message.data))
            h = msg.header
            out["header"].append(h.stamp.sec * 1_000_000_000 + h.stamp.nanosec)
            out["frame"].append(h.frame_id)
            if schema.name == TRANSFORM:
                tr, rot = msg.transform.translation, msg.transform.rotation
                out["pose"].append((tr.x, tr.y, tr.z, rot.x, rot.y, rot.z, rot.w))
                continue
            p = msg.pose.pose if schema.name == ODOMETRY else msg.pose
            q = p.orientation
            out["pose"].append((p.position.x, p.position.y, p.position.z, q.x, q.y, q.z, q.w))
            if schema.name == ODOMETRY:
                lin = msg.twist.twist.linear
                out["twist"].append((lin.x, lin.y, lin.z))
    return out


BAGS = {
    "plain-none-small": lambda d: write_plain(d / "a.mcap", "none", 3_000),
    "plain-zstd-small": lambda d: write_plain(d / "b.mcap", "zstd", 3_000),
    "plain-lz4-small": lambda d: write_plain(d / "c.mcap", "lz4", 3_000),
    "plain-zstd-big": lambda d: write_plain(d / "d.mcap", "zstd", 1 << 20),
    "plain-none-big": lambda d: write_plain(d / "e.mcap", "none", 1 << 20),
    "rosbag2-none": lambda d: write_rosbag2(d / "r2", zstd_chunks=False),
    "rosbag2-zstd": lambda d: write_rosbag2(d / "r2z", zstd_chunks=True),
}


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("mcapchunks")
    return {k: make(d) for k, make in BAGS.items()}


def _summary(bag: Path) -> Any:
    return mcapchunks.read_summary(_mcap_file(bag))


@pytest.mark.parametrize("key", list(BAGS))
def test_bags_have_the_chunk_layouts_they_claim(bags: dict[str, Path], key: str) -> None:
    s = _summary(bags[key])
    comp = {c.compression for c in s.chunk_indexes}
    assert comp == {"zstd" if "zstd" in key else "lz4" if "lz4" in key else ""}
    per_chunk = [len(c.message_index_offsets) for c in s.chunk_indexes]
    if "small" in key:  # a topic spans many chunks, and most chunks still mix channels
        assert len(s.chunk_indexes) > 50
    else:  # one chunk holds every channel, camera images included
        assert max(per_chunk) == 4


@pytest.mark.parametrize("key", list(BAGS))
def test_batches_are_the_mcap_readers_messages(bags: dict[str, Path], key: str) -> None:
    """Byte for byte and in order, the message data the chunk decoder slices out."""
    bag = bags[key]
    s = _summary(bag)
    wanted = {cid: k for k, (cid, ch) in enumerate(s.channels.items()) if ch.topic in TOPICS}
    got: dict[int, list[tuple[int, bytes]]] = {k: [] for k in wanted.values()}
    for b in mcapchunks.mcap_batches(_mcap_file(bag), s, wanted):
        for st, en, lg, c in zip(b.starts, b.ends, b.log_ns, b.conn, strict=True):
            got[int(c)].append((int(lg), bytes(b.buf[st:en])))
    for cid, k in wanted.items():
        ref = reference(bag, s.channels[cid].topic)
        order = np.argsort([lg for lg, _ in got[k]], kind="stable")
        assert [got[k][j][0] for j in order] == ref["log"]
        assert [got[k][j][1] for j in order] == ref["data"]


@pytest.mark.parametrize("key", list(BAGS))
def test_read_equals_reader_and_deserializer(bags: dict[str, Path], key: str) -> None:
    """Record for record: log time, header stamp, pose, twist, frame names."""
    bag = bags[key]
    with BagSource(bag) as src:
        infos = [t for t in src.topics() if t.topic in TOPICS]
        assert sorted(src._indexed_fast(infos, NULL_PROGRESS)) == sorted(TOPICS)  # no fallback
        trajs = src.read_many([(t, None) for t in TOPICS])
    for tr in trajs:
        ref = reference(bag, tr.name)
        assert tr.decoder == "numpy" and len(tr) == N
        np.testing.assert_array_equal(tr.log_ns, ref["log"])
        np.testing.assert_array_equal(tr.header_ns, ref["header"])
        np.testing.assert_array_equal(np.hstack([tr.position, tr.orientation]), ref["pose"])
        assert tr.frame_id == ref["frame"][0]
        if tr.msgtype == ODOMETRY:
            assert tr.velocity is not None
            np.testing.assert_array_equal(tr.velocity, ref["twist"])
        assert len({len(f) for f in ref["frame"]}) == 7  # the frame lengths did vary


def test_message_index_equals_mcaps_parser(bags: dict[str, Path]) -> None:
    from mcap.data_stream import ReadDataStream
    from mcap.records import MessageIndex

    f = _mcap_file(bags["plain-zstd-small"])
    buf = np.memmap(f, dtype=np.uint8, mode="r")
    s = _summary(f)
    checked = 0
    with open(f, "rb") as fh:
        for ch in s.chunk_indexes:
            for cid, off in ch.message_index_offsets.items():
                fh.seek(off + 9)
                ref = MessageIndex.read(ReadDataStream(fh))
                assert ref.channel_id == cid
                assert mcapchunks.message_index(buf, off, cid).tolist() == [
                    list(r) for r in ref.records
                ]
                checked += 1
    assert checked > 100


def _unindexed(d: Path, name: str, **opts: Any) -> Path:
    return write_plain(d / name, "zstd", 3_000, **opts)


@pytest.mark.parametrize(
    "opts",
    [
        {"use_chunking": False},  # no chunks, no chunk index
        {"index_types": IndexType.CHUNK},  # chunk indexes without message indexes
    ],
    ids=["no-chunks", "no-message-index"],
)
def test_unindexed_files_fall_back_to_the_reader(tmp_path: Path, opts: dict) -> None:
    bag = _unindexed(tmp_path, "u.mcap", **opts)
    s = _summary(bag)
    with pytest.raises(layout.LayoutError):
        list(mcapchunks.mcap_batches(bag, s, dict.fromkeys(s.channels, 0)))
    with BagSource(bag) as src:
        infos = [t for t in src.topics() if t.topic in TOPICS]
        assert src._indexed_fast(infos, NULL_PROGRESS) == {}
        tr = src.read("/vio/odom")
    ref = reference(bag, "/vio/odom")
    np.testing.assert_array_equal(tr.log_ns, ref["log"])
    np.testing.assert_array_equal(np.hstack([tr.position, tr.orientation]), ref["pose"])


@pytest.mark.parametrize("key", ["plain-zstd-big", "plain-none-small", "rosbag2-zstd"])
@pytest.mark.parametrize("frac", [0.3, 0.97])
def test_truncated_file_is_refused_in_one_line(
    bags: dict[str, Path], tmp_path: Path, key: str, frac: float
) -> None:
    import shutil

    src_bag = bags[key]
    bag = tmp_path / src_bag.name
    if src_bag.is_dir():
        shutil.copytree(src_bag, bag)
    else:
        shutil.copy(src_bag, bag)
    f = _mcap_file(bag)
    data = f.read_bytes()
    f.write_bytes(data[: int(len(data) * frac)])
    with pytest.raises(InputError) as err, BagSource(bag) as src:
        src.read("/vio/odom")
    msg = str(err.value)
    assert "\n" not in msg and "truncated or damaged" in msg
    assert ("mcap recover" if bag.is_file() else "ros2 bag reindex") in msg


def test_damaged_chunk_is_refused_in_one_line(bags: dict[str, Path], tmp_path: Path) -> None:
    """Summary intact, one zstd chunk's compressed bytes overwritten."""
    f = tmp_path / "dmg.mcap"
    data = bytearray(_mcap_file(bags["plain-zstd-small"]).read_bytes())
    ch = sorted(_summary(bags["plain-zstd-small"]).chunk_indexes,
                key=lambda c: c.chunk_start_offset)[5]  # fmt: skip
    end = ch.chunk_start_offset + ch.chunk_length
    data[end - ch.compressed_size : end] = bytes(ch.compressed_size)
    f.write_bytes(bytes(data))
    with pytest.raises(InputError) as err, BagSource(f) as src:
        src.read("/vio/odom")
    assert "\n" not in str(err.value) and "truncated or damaged" in str(err.value)


@pytest.mark.parametrize("key", ["plain-zstd-small", "plain-lz4-small"])
def test_many_batches_in_the_reused_buffer(
    bags: dict[str, Path], key: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Batches of ~20 kB (the buffer is overwritten by every next batch) read the same."""
    monkeypatch.setattr(mcapchunks, "_BATCH_BYTES", 20_000)
    bag = bags[key]
    s = _summary(bag)
    wanted = {cid: 0 for cid, ch in s.channels.items() if ch.topic == "/vio/odom"}
    assert len(list(mcapchunks.mcap_batches(_mcap_file(bag), s, wanted))) > 5
    with BagSource(bag) as src:
        tr = src.read("/vio/odom")
    ref = reference(bag, "/vio/odom")
    assert tr.decoder == "numpy"
    np.testing.assert_array_equal(tr.log_ns, ref["log"])
    np.testing.assert_array_equal(tr.header_ns, ref["header"])
    np.testing.assert_array_equal(np.hstack([tr.position, tr.orientation]), ref["pose"])
    np.testing.assert_array_equal(tr.velocity, ref["twist"])


def test_rosbag2_split_into_two_mcap_files(tmp_path: Path) -> None:
    """A bag split into two storage files whose channel ids differ: read as one topic."""
    import yaml

    rows = _schedule()
    a = write_rosbag2(tmp_path / "a", False, rows[: len(rows) // 2])
    b = write_rosbag2(tmp_path / "b", True, rows[len(rows) // 2 :], rev=True)
    (b / "b.mcap").rename(a / "a_1.mcap")
    meta_a, meta_b = (yaml.safe_load((x / "metadata.yaml").read_text()) for x in (a, b))
    info, other = meta_a["rosbag2_bagfile_information"], meta_b["rosbag2_bagfile_information"]
    info["relative_file_paths"].append("a_1.mcap")
    info["files"].append({**other["files"][0], "path": "a_1.mcap"})
    info["message_count"] += other["message_count"]
    counts = {
        t["topic_metadata"]["name"]: t["message_count"] for t in other["topics_with_message_count"]
    }
    for t in info["topics_with_message_count"]:
        t["message_count"] += counts[t["topic_metadata"]["name"]]
    (a / "metadata.yaml").write_text(yaml.safe_dump(meta_a))
    ids = [
        {ch.topic: cid for cid, ch in _summary(f).channels.items()}
        for f in (a / "a.mcap", a / "a_1.mcap")
    ]
    assert ids[0]["/vio/odom"] != ids[1]["/vio/odom"]
    with BagSource(a) as src:
        infos = [t for t in src.topics() if t.topic in TOPICS]
        assert sorted(src._indexed_fast(infos, NULL_PROGRESS)) == sorted(TOPICS)
        trajs = src.read_many([(t, None) for t in TOPICS])
    for tr in trajs:
        ref = [reference(f, tr.name) for f in (a / "a.mcap", a / "a_1.mcap")]
        assert tr.decoder == "numpy" and len(tr) == N
        np.testing.assert_array_equal(tr.log_ns, ref[0]["log"] + ref[1]["log"])
        np.testing.assert_array_equal(tr.header_ns, ref[0]["header"] + ref[1]["header"])
        np.testing.assert_array_equal(
            np.hstack([tr.position, tr.orientation]), ref[0]["pose"] + ref[1]["pose"]
        )


@pytest.mark.parametrize("compression", ["none", "zstd"])
def test_frame_names_come_from_the_earliest_message(tmp_path: Path, compression: str) -> None:
    """Chunks out of log-time order, the frame name changing within the topic: the fast path
    names the frames of the first message in log time, as the per-message path does."""
    from mcap.writer import CompressionType, Writer

    ts = typestore(ros1=False)
    f = tmp_path / "order.mcap"
    with open(f, "wb") as fh:
        w = Writer(fh, compression=CompressionType[compression.upper()], chunk_size=800)
        w.start(profile="ros2", library="qsls-test")
        msgdef, _ = ts.generate_msgdef(POSE_STAMPED, ros_version=2)
        sid = w.register_schema(name=POSE_STAMPED, encoding="ros2msg", data=msgdef.encode())
        ch = w.register_channel(topic="/pose", message_encoding="cdr", schema_id=sid)
        for k, (log0, frame) in enumerate(((T0 + 10**9, "odom"), (T0, "map"))):
            for i in range(50):
                t = ts.types
                hdr = t["std_msgs/msg/Header"](
                    stamp=t["builtin_interfaces/msg/Time"](sec=1000 + 50 * k + i, nanosec=0),
                    frame_id=frame,
                )
                pose = t["geometry_msgs/msg/Pose"](
                    position=t["geometry_msgs/msg/Point"](x=float(i), y=0.0, z=1.0),
                    orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                )
                msg = t[POSE_STAMPED](header=hdr, pose=pose)
                data = bytes(ts.serialize_cdr(msg, POSE_STAMPED))
                w.add_message(ch, log_time=log0 + i, data=data, publish_time=log0 + i, sequence=i)
        w.finish()
    with BagSource(f) as src:
        fast, slow = src.read("/pose", fast=True), src.read("/pose", fast=False)
    assert fast.decoder == "numpy" and slow.decoder != "numpy"
    assert fast.frame_id == slow.frame_id == "map"
    np.testing.assert_array_equal(fast.log_ns, slow.log_ns)
    np.testing.assert_array_equal(fast.header_ns, slow.header_ns)


def test_a_chunk_index_whose_size_lies_is_a_layout_error(bags: dict[str, Path]) -> None:
    """An index claiming 16 TiB (or 16 bytes more) for a chunk: LayoutError (the caller falls
    back to the per-message reader), before anything is allocated from the claim."""
    bag = bags["plain-zstd-small"]
    for claim in (1 << 44, None):
        summary = _summary(bag)
        first = min(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
        first.uncompressed_size = claim if claim else first.uncompressed_size + 16
        wanted = {c.id: 0 for c in summary.channels.values() if c.topic == "/vio/odom"}
        with pytest.raises(layout.LayoutError, match="another size than its index says"):
            list(mcapchunks.mcap_batches(_mcap_file(bag), summary, wanted))


# ------------------------------------------------------- damage the summary cannot hide (issue 35)
def _chunks(f: Path) -> list[Any]:
    return sorted(mcapchunks.read_summary(f).chunk_indexes, key=lambda c: c.chunk_start_offset)


def _vio_x_positions(f: Path, n: int) -> list[tuple[int, float]]:
    """(file offset of the ``pose.position.x`` double, x) of ``n`` VIO messages in the
    middle of the file, found by their unique serialized bytes."""
    from mcap.reader import make_reader

    ts = typestore(ros1=False)
    data = f.read_bytes()
    out = []
    with open(f, "rb") as fh:
        msgs = list(make_reader(fh).iter_messages(topics=["/vio/odom"]))
    for _, _, message in msgs[len(msgs) // 2 : len(msgs) // 2 + n]:
        raw = bytes(message.data)
        x = ts.deserialize_cdr(raw, ODOMETRY).pose.pose.position.x
        at = data.find(raw)
        assert at > 0 and data.find(raw, at + 1) < 0
        inner = raw.find(np.float64(x).tobytes())
        assert inner > 0
        out.append((at + inner, float(x)))
    return out


def test_a_chunk_whose_crc_fails_is_refused_naming_it(tmp_path: Path) -> None:
    """20 VIO x positions moved by 0.5 m inside uncompressed chunks: every record still
    where the index says, only the chunk CRCs tell (the ``mcap`` reader raises on them)."""
    f = write_plain(tmp_path / "crc.mcap", "none", 1 << 20)
    data = bytearray(f.read_bytes())
    for at, x in _vio_x_positions(f, 20):
        data[at : at + 8] = np.float64(x + 0.5).tobytes()
    f.write_bytes(bytes(data))
    ch = _chunks(f)[0]
    with pytest.raises(InputError) as err, BagSource(f) as src:
        src.read("/vio/odom")
    msg = str(err.value)
    assert "\n" not in msg and "CRC" in msg
    assert f"MCAP chunk 1 (at byte {ch.chunk_start_offset})" in msg and "mcap recover" in msg


def test_a_compressed_chunk_whose_crc_fails_is_refused(tmp_path: Path) -> None:
    """A zstd chunk whose data decompresses fine but whose stored CRC does not match it."""
    f = write_plain(tmp_path / "crcz.mcap", "zstd", 3_000)
    data = bytearray(f.read_bytes())
    ch = _chunks(f)[3]
    at = ch.chunk_start_offset + mcapchunks._CRC_AT
    data[at] ^= 0x01
    f.write_bytes(bytes(data))
    with pytest.raises(InputError) as err, BagSource(f) as src:
        src.read("/vio/odom")
    assert "MCAP chunk 4 " in str(err.value) and "CRC" in str(err.value)


def test_the_cli_refuses_a_crc_failure_in_one_line(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from qsls.cli.main import app

    f = write_plain(tmp_path / "crc.mcap", "none", 1 << 20)
    data = bytearray(f.read_bytes())
    for at, x in _vio_x_positions(f, 20):
        data[at : at + 8] = np.float64(x + 0.5).tobytes()
    f.write_bytes(bytes(data))
    res = CliRunner().invoke(
        app, ["ingest", str(f), "--vio-topic", "/vio/odom", "--truth-topic", "/mocap/pose",
              "--out", str(tmp_path / "out")],
    )  # fmt: skip
    text = res.output.strip()
    assert res.exit_code != 0 and "\n" not in text and text.startswith("error: "), text
    assert "CRC" in text and not (tmp_path / "out").exists()


def test_a_damaged_record_that_ends_its_chunk_early_is_refused(tmp_path: Path) -> None:
    """No CRCs stored (a writer may leave them out): a message record claiming 2 GB makes
    the per-message reader drop the rest of the chunk silently; the summary's per-channel
    counts tell, and the read is refused."""
    f = write_plain(tmp_path / "rec.mcap", "none", 1 << 20, enable_crcs=False)
    data = bytearray(f.read_bytes())
    # the record head of that message: find its MESSAGE opcode before the data
    from mcap.reader import make_reader

    with open(f, "rb") as fh:
        msgs = list(make_reader(fh).iter_messages(topics=["/vio/odom"]))
    raw = bytes(msgs[len(msgs) // 2][2].data)
    head = data.find(raw) - mcapchunks._MSG_HEAD
    assert data[head] == 0x05  # Opcode.MESSAGE
    data[head + 1 : head + 9] = (2 << 30).to_bytes(8, "little")
    f.write_bytes(bytes(data))
    with open(f, "rb") as fh:  # what the reader alone gives: a silent loss
        kept = sum(1 for _ in make_reader(fh).iter_messages(topics=["/vio/odom"]))
    assert kept < N
    with pytest.raises(InputError) as err, BagSource(f) as src:
        src.read("/vio/odom")
    msg = str(err.value)
    assert "\n" not in msg and f"where the bag's index lists {N}" in msg, msg
    assert "truncated or damaged" in msg
