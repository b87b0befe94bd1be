"""Bad input: one-line error that says what to do, non-zero exit, no output left behind."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from qsls.cli.main import app
from qsls.pipeline.ingest.sources.messages import ImageStream, OdometryStream, PoseStream
from qsls.pipeline.ingest.sources.write import write_bag
from tests.bagfixtures import make_flight

runner = CliRunner()


@pytest.fixture(scope="module")
def flight():
    return make_flight(duration=12.0, dropouts=())


@pytest.fixture(scope="module")
def good_bag(tmp_path_factory: pytest.TempPathFactory, flight) -> Path:
    d = tmp_path_factory.mktemp("good")
    cam = ImageStream("/cam/image", flight.vio.header_ns[::50], flight.vio.log_ns[::50], 8, 8)
    return write_bag(d / "good.bag", [flight.vio, flight.truth, cam], "ros1")


def _fails(tmp_path: Path, args: list[str], *expect: str) -> str:
    out = tmp_path / "out"
    res = runner.invoke(app, ["ingest", *args, "--out", str(out)])
    text = res.output.strip()
    assert res.exit_code != 0, text
    assert text.startswith("error: ") and "\n" not in text, text
    assert "Traceback" not in text
    for e in expect:
        assert e in text, text
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out")]
    return text


def test_missing_file(tmp_path: Path) -> None:
    _fails(tmp_path, [str(tmp_path / "nope.bag")], "no such file")


def test_no_input_at_all(tmp_path: Path) -> None:
    _fails(tmp_path, [], "no input")


def test_empty_file(tmp_path: Path) -> None:
    (tmp_path / "e.bag").write_bytes(b"")
    _fails(tmp_path, [str(tmp_path / "e.bag")], "empty")
    (tmp_path / "e.txt").write_text("# only a comment\n")
    _fails(
        tmp_path, ["--vio", str(tmp_path / "e.txt"), "--truth", str(tmp_path / "e.txt")], "empty"
    )


def test_not_a_bag(tmp_path: Path) -> None:
    (tmp_path / "x.bag").write_bytes(np.random.default_rng(0).bytes(5000))
    _fails(tmp_path, [str(tmp_path / "x.bag")], "not a bag")
    (tmp_path / "notes.txt").write_text("hello world\nthis is not a trajectory\n")
    _fails(tmp_path, [str(tmp_path / "notes.txt")], "not a bag")
    (tmp_path / "folder").mkdir()
    _fails(tmp_path, [str(tmp_path / "folder")], "metadata.yaml")


@pytest.mark.parametrize("fmt", ["ros1", "mcap", "ros2-sqlite"])
def test_truncated_bag(tmp_path: Path, flight, fmt: str) -> None:
    bag = write_bag(
        tmp_path / {"ros1": "t.bag", "mcap": "t.mcap"}.get(fmt, "t"),
        [flight.vio, flight.truth],
        fmt,
    )
    f = bag if bag.is_file() else next(bag.glob("*.db3"))
    data = f.read_bytes()
    f.write_bytes(data[: len(data) // 2])
    tool = {"ros1": "rosbag reindex", "mcap": "mcap recover"}.get(fmt, "ros2 bag reindex")
    msg = _fails(tmp_path, [str(bag)], "truncated or damaged", tool)
    assert fmt != "mcap" or "reindex" not in msg  # a plain MCAP has no rosbag2 metadata


def test_topic_not_there(tmp_path: Path, good_bag: Path) -> None:
    msg = _fails(
        tmp_path,
        [str(good_bag), "--vio-topic", "/odom"],
        "no topic /odom",
        "/vio/odom (nav_msgs/msg/Odometry, 600 msgs)",
        "/mocap/pose",
    )
    assert "/cam/image (sensor_msgs/msg/Image" in msg


def test_topic_of_wrong_type(tmp_path: Path, good_bag: Path) -> None:
    _fails(
        tmp_path,
        [str(good_bag), "--truth-topic", "/cam/image"],
        "/cam/image is sensor_msgs/msg/Image",
    )
    _fails(tmp_path, [str(good_bag), "--vio-topic", "/cam/image"], "not a vio message type")


def test_ambiguous_topics_list_candidates(tmp_path: Path, flight) -> None:
    other = replace(flight.vio, topic="/vins/odometry")
    bag = write_bag(tmp_path / "amb.bag", [flight.vio, other, flight.truth], "ros1")
    _fails(
        tmp_path,
        [str(bag)],
        "cannot choose the VIO topic",
        "/vins/odometry (nav_msgs/msg/Odometry, 600 msgs)",
        "--vio-topic",
    )


def test_tf_without_frame_lists_pairs(tmp_path: Path, flight) -> None:
    t = flight.truth
    tf = PoseStream(
        "/tf",
        t.header_ns,
        t.log_ns,
        t.position,
        t.orientation,
        msgtype="tf2_msgs/msg/TFMessage",
        frame_id="map",
        child_frame_id="quad",
    )
    bag = write_bag(tmp_path / "tf.mcap", [flight.vio, tf], "mcap")
    _fails(tmp_path, [str(bag), "--truth-topic", "/tf"], "--truth-frame")
    _fails(
        tmp_path,
        [str(bag), "--truth-topic", "/tf", "--truth-frame", "map/imu"],
        "no transform map/imu",
        "map/quad (",
    )


def test_streams_that_do_not_overlap(tmp_path: Path, flight) -> None:
    late = replace(flight.truth, header_ns=flight.truth.header_ns + 1000 * 10**9)
    bag = write_bag(tmp_path / "far.bag", [flight.vio, late], "ros1")
    _fails(tmp_path, [str(bag)], "do not overlap", "--time-offset")
    # overlapping only 2 s
    short = replace(flight.truth, header_ns=flight.truth.header_ns + 11 * 10**9)
    bag2 = write_bag(tmp_path / "short.bag", [flight.vio, short], "ros1")
    _fails(tmp_path, [str(bag2)], "overlap only")
    # an offset beyond the search range is not silently accepted
    off = replace(flight.truth, header_ns=flight.truth.header_ns + 3 * 10**9)
    bag3 = write_bag(tmp_path / "off.bag", [flight.vio, off], "ros1")
    _fails(tmp_path, [str(bag3)], "do not match at any clock offset", "--max-time-offset")
    res = runner.invoke(
        app, ["ingest", str(bag3), "--out", str(tmp_path / "ok"), "--max-time-offset", "4"]
    )
    assert res.exit_code == 0, res.output
    m = json.loads((tmp_path / "ok" / "manifest.json").read_text())["results"]
    assert abs(m["time_offset_s"] - (flight.offset_s - 3.0)) < 0.005


def test_nan_and_inf_values(tmp_path: Path, flight) -> None:
    p = flight.vio.position.copy()
    p[[40, 41], 0] = np.nan
    v = flight.vio.linear_velocity.copy()
    v[77, 2] = np.inf
    vio = OdometryStream(
        flight.vio.topic, flight.vio.header_ns, flight.vio.log_ns, p, flight.vio.orientation, v
    )
    bag = write_bag(tmp_path / "nan.bag", [vio, flight.truth], "ros1")
    _fails(tmp_path, [str(bag)], "3 of 600 messages", "--drop-nonfinite")
    res = runner.invoke(
        app, ["ingest", str(bag), "--out", str(tmp_path / "ok"), "--drop-nonfinite"]
    )
    assert res.exit_code == 0, res.output
    m = json.loads((tmp_path / "ok" / "manifest.json").read_text())["results"]
    assert m["nonfinite_dropped"] == {"vio": 3, "truth": 0}


def test_bad_options(tmp_path: Path, good_bag: Path) -> None:
    _fails(tmp_path, [str(good_bag), "--time-offset", "soon"], "--time-offset")
    _fails(tmp_path, [str(good_bag), "--align", "sim3"], "align")
    _fails(tmp_path, [str(good_bag), "--truth-frame", "world"], "PARENT/CHILD")
    cfg = tmp_path / "c.yaml"
    cfg.write_text("max_gapp: 1\n")
    _fails(tmp_path, [str(good_bag), "--config", str(cfg)], "did you mean 'max_gap'")


def test_a_truth_jump_is_found_and_becomes_a_gap():
    """A motion-capture track that jumps 0.5 m for one sample and comes back (two intervals no
    vehicle flies) and one that re-acquires 5 cm off (one interval) are found, a smooth
    1 m/s track with 1 mm noise is not, and the samples within half a gap of each jump are
    the ones dropped."""
    from qsls.pipeline.ingest.streams import drop_around, truth_jumps

    t = np.arange(200) * 10_000_000  # 100 Hz
    p = np.c_[np.arange(200) * 0.01, np.zeros(200), np.ones(200)]
    p += np.random.default_rng(0).normal(0, 0.001, p.shape)
    assert len(truth_jumps(t, p, 100.0)) == 0
    spike = p.copy()
    spike[100, 1] += 0.5
    np.testing.assert_array_equal(truth_jumps(t, spike, 100.0), [99, 100])
    step = p.copy()
    step[120:, 0] += 0.05
    np.testing.assert_array_equal(truth_jumps(t, step, 100.0), [119])
    bad = drop_around(t, np.array([119]), 25_000_000)  # half of a 0.05 s gap
    np.testing.assert_array_equal(np.flatnonzero(bad), [117, 118, 119, 120, 121, 122])


@pytest.fixture(scope="module")
def simulated_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("sim")
    res = runner.invoke(app, ["simulate", "--duration", "8", "--out", str(d / "sim")])
    assert res.exit_code == 0, res.output
    return d / "sim" / "flight.bag"


@pytest.mark.parametrize(
    "topics",
    [
        ["--vio-topic", "/vicon/quad/pose", "--truth-topic", "/vio/odometry"],
        ["--vio-topic", "/vicon/quad/pose"],
    ],
    ids=["swapped", "vio-is-the-pose"],
)
def test_swapped_topics_are_one_line(tmp_path: Path, simulated_bag: Path, topics) -> None:
    """Issue 35: the VIO odometry as truth lost every sample to the jump filter, then
    IndexError at ingest/stage.py:143."""
    _fails(tmp_path, [str(simulated_bag), *topics], "truth stream /vio/odometry", "swapped?")


def test_a_locked_sqlite_bag_is_called_locked_not_damaged(tmp_path: Path, flight) -> None:
    """Issue 35: a database another program holds locked was "truncated or damaged"."""
    import sqlite3

    bag = write_bag(tmp_path / "locked", [flight.vio, flight.truth], "ros2-sqlite")
    holder = sqlite3.connect(next(bag.glob("*.db3")), isolation_level=None)
    holder.execute("BEGIN EXCLUSIVE")  # a recorder in the middle of a write
    try:
        text = _fails(tmp_path, [str(bag)], "locked by another program")
    finally:
        holder.close()
    assert "damaged" not in text


@pytest.mark.parametrize(
    "wrong", ["geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/PoseWithCovarianceStamped"]
)
def test_a_metadata_yaml_with_the_wrong_type_says_so(tmp_path: Path, flight, wrong) -> None:
    """Issue 35: a metadata.yaml listing the VIO topic as another type was a damaged bag."""
    bag = write_bag(tmp_path / "retyped", [flight.vio, flight.truth], "ros2-sqlite")
    meta = bag / "metadata.yaml"
    meta.write_text(meta.read_text().replace("nav_msgs/msg/Odometry", wrong))
    _fails(tmp_path, [str(bag), "--vio-topic", "/vio/odom", "--truth-topic", "/mocap/pose"],
           "do not decode as the types its metadata.yaml lists", f"/vio/odom as {wrong}")  # fmt: skip


def test_a_clock_that_jumps_back_is_named(tmp_path: Path, flight) -> None:
    """Issue 35: a 5 s backward jump of the truth's clock was 'the streams do not match at
    any clock offset'; the TUM reader names the line, the bag reader now the message."""
    h = flight.truth.header_ns.copy()
    k = len(h) // 2
    h[k:] -= 5_000_000_000
    bag = write_bag(tmp_path / "jump.bag", [flight.vio, replace(flight.truth, header_ns=h)], "ros1")
    _fails(tmp_path, [str(bag)], f"its clock jumps back 4.99 s at message {k}", "--stamp log")


def test_a_twist_frame_the_positions_contradict_is_refused(
    tmp_path: Path, simulated_bag: Path
) -> None:
    """Issue 35: --vio-velocity-frame world on a body-frame bag gave a large velocity error
    without a word; the VIO's own positions tell which frame its twist is in."""
    _fails(tmp_path, [str(simulated_bag), "--vio-velocity-frame", "world"],
           "its twist read in the world frame", "pass --vio-velocity-frame body")  # fmt: skip
    ok = runner.invoke(app, ["ingest", str(simulated_bag), "--out", str(tmp_path / "ok")])
    assert ok.exit_code == 0, ok.output
