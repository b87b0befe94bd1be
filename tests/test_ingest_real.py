"""Real EuRoC estimates and ground truth (../shared/data/real), written into bags at test time.

evo's number is computed independently here the way ``evo_ape --align`` does it: pairs
associated by timestamp (for each stamp of the shorter trajectory the nearest of the other,
kept when within 0.01 s), Umeyama SE(3) alignment of the pairs, RMS of the translation
errors. ``--t_offset`` (evo's constant stamp offset) is applied as our estimate when
comparing against our auto-synchronized result.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from qsls.pipeline.ingest.align import differentiate, fit_alignment
from qsls.pipeline.ingest.flight import read_flight
from qsls.pipeline.ingest.sources.base import Trajectory
from qsls.pipeline.ingest.sources.messages import PoseStream
from qsls.pipeline.ingest.sources.text.reader import read_euroc, read_tum
from qsls.pipeline.ingest.sources.write import write_bag
from qsls.pipeline.ingest.stage import IngestOptions, ingest

PAIRS = {
    "euroc_v102": ("groundtruth.csv", "ros1"),
    "euroc_v102_rpg": ("groundtruth_tum.txt", "ros2-sqlite"),
    "euroc_mh04_rpg": ("groundtruth_tum.txt", "mcap"),
}
SHIFT_NS = 80_000_000  # the second copy's truth clock reads 0.08 s later


def _evo_ape_rmse(est: Trajectory, ref: Trajectory, offset_ref_s: float = 0.0) -> float:
    ts = est.header_ns * 1e-9
    tr = ref.header_ns * 1e-9 + offset_ref_s
    if len(ts) > len(tr):
        raise AssertionError("fixture: the estimate is the shorter trajectory")
    pairs = []
    for i, s in enumerate(ts):
        j = int(np.argmin(np.abs(tr - s)))
        if abs(tr[j] - s) <= 0.01:
            pairs.append((i, j))
    i1, i2 = np.array(pairs).T
    a, b = est.position[i1], ref.position[i2]
    al = fit_alignment(a, b, "se3")
    r = al.apply(a) - b
    return float(np.sqrt(np.mean(np.sum(r * r, axis=1))))


def _stream(topic: str, t: Trajectory, shift_ns: int = 0) -> PoseStream:
    ns = t.header_ns + shift_ns
    return PoseStream(topic, ns, ns, t.position, t.orientation, frame_id="world")


@pytest.mark.real
@pytest.mark.parametrize("name", list(PAIRS))
def test_real_offsets_and_rms_against_evo(real_data: Path, tmp_path: Path, name: str) -> None:
    gt_file, fmt = PAIRS[name]
    est = read_tum(real_data / name / "estimate_tum.txt")
    ref = (read_euroc if gt_file.endswith(".csv") else read_tum)(real_data / name / gt_file)
    ext = {"ros1": ".bag", "mcap": ".mcap"}.get(fmt, "")
    o = IngestOptions(vio_topic="/estimate", truth_topic="/groundtruth", align="se3")
    results = []
    for k, shift in enumerate((0, SHIFT_NS)):
        bag = write_bag(
            tmp_path / f"copy{k}{ext}",
            [_stream("/estimate", est), _stream("/groundtruth", ref, shift)],
            fmt,
        )
        results.append(ingest([bag], o, tmp_path / f"out{k}"))
    a, b = results
    # the estimator's own latency makes the offset non-zero; the copies differ by the shift
    assert abs((a.time_offset_s - b.time_offset_s) - SHIFT_NS * 1e-9) < 0.005
    assert -0.1 < a.time_offset_s < 0.1
    # RMS after alignment against evo's computation on the same pair and offset
    evo = _evo_ape_rmse(est, ref, a.time_offset_s)
    assert abs(a.rms_position_m - evo) < 0.1 * evo, (a.rms_position_m, evo)
    o0 = o.model_copy(update={"time_offset": 0.0})
    c = ingest([tmp_path / f"copy0{ext}"], o0, tmp_path / "zero")
    evo0 = _evo_ape_rmse(est, ref, 0.0)
    assert abs(c.rms_position_m - evo0) < 0.1 * evo0, (c.rms_position_m, evo0)
    m = json.loads((tmp_path / "out0" / "manifest.json").read_text())["results"]
    assert m["duplicates_dropped"]["vio"] == (4 if name == "euroc_v102" else 0)
    assert "differentiator" in m["velocity_source"]["vio"]


@pytest.mark.real
def test_truth_velocity_against_euroc(real_data: Path, tmp_path: Path) -> None:
    """The smoothing differentiator against the EuRoC csv's own velocity."""
    ref = read_euroc(real_data / "euroc_v102" / "groundtruth.csv")
    v = differentiate(ref.header_ns, ref.position, 0.1, 250_000_000)
    err = v - ref.velocity
    rms = float(np.sqrt(np.mean(np.sum(err**2, axis=1))))
    speed = float(np.sqrt(np.mean(np.sum(ref.velocity**2, axis=1))))
    assert rms < 0.01 < 0.5 < speed
    # and through the whole stage: x_v* of flight.parquet against the csv velocity
    est = read_tum(real_data / "euroc_v102" / "estimate_tum.txt")
    r = ingest([], IngestOptions(vio=real_data / "euroc_v102" / "estimate_tum.txt",
                                 truth=real_data / "euroc_v102" / "groundtruth.csv"), tmp_path / "o")  # fmt: skip
    df = read_flight(tmp_path / "o")
    t_truth = df["stamp_ns"].to_numpy() - round(r.time_offset_s * 1e9)
    csv_v = np.column_stack(
        [np.interp(t_truth, ref.header_ns, ref.velocity[:, k]) for k in range(3)]
    )
    got = df[["x_vx", "x_vy", "x_vz"]].to_numpy()
    assert float(np.sqrt(np.mean(np.sum((got - csv_v) ** 2, axis=1)))) < 0.01
    assert len(df) > 0.95 * (est.header_ns[-1] - est.header_ns[0]) * 1e-9 / 0.1


@pytest.mark.real
def test_real_bags_read(real_data: Path, tmp_path: Path) -> None:
    """The published real-world bags: ROS1 PoseStamped, ROS2 MCAP Odometry, TF in ROS1 and ROS2."""
    from qsls.pipeline.ingest.sources.bags import BagSource

    bags = real_data / "bags"
    with BagSource(bags / "ROS_example.bag") as s:
        fast, slow = s.read("groundtruth"), s.read("groundtruth", fast=False)
        assert fast.decoder == "numpy" and len(fast) == 12765
        np.testing.assert_array_equal(fast.position, slow.position)
    with BagSource(bags / "nav2_turtlebot.mcap") as s:
        odo = s.read("/odom")
        assert odo.decoder == "numpy" and len(odo) == 2639
        np.testing.assert_array_equal(odo.velocity, s.read("/odom", fast=False).velocity)
        # header stamps are simulation time, log time is wall clock
        assert odo.header_ns[0] < 10**13 < odo.log_ns[0]
    for p in (bags / "tf_example.bag", bags / "tf_example_ros2"):
        with BagSource(p) as s:
            tf = s.read("/tf", truth_frame="odom/base_footprint")
            assert len(tf) == 517 and np.isfinite(tf.position).all()


@pytest.mark.real
def test_real_bags_as_sqlite3_come_as_trimmed_records(real_data: Path, tmp_path: Path) -> None:
    """The real ROS1 PoseStamped bag and the ROS2 Odometry MCAP, converted to rosbag2 sqlite3
    by rosbags' converter: every topic is fetched as trimmed records (84-byte PoseStamped,
    148-byte Odometry: its covariances are all zero) and decodes as rosbags' deserializer
    decodes the whole messages."""
    from rosbags.convert.converter import convert

    from qsls.pipeline.ingest.sources.bags import BagSource
    from qsls.pipeline.ingest.sources.rosbag2.listing import open_rosbag2
    from qsls.pipeline.ingest.sources.rosbag2.sqlite import sqlite_batches

    cases = {"ROS_example.bag": ({"ORB-SLAM", "S-PTAM", "groundtruth"}, 84),
             "nav2_turtlebot.mcap": ({"/odom"}, 148)}  # fmt: skip
    for name, (topics, size) in cases.items():
        dst = tmp_path / name.split(".")[0]
        src = real_data / "bags" / name
        convert([src], dst, "sqlite3", 8, None, "none", None, None, [], sorted(topics), [], [])
        with BagSource(dst) as s:
            types = {t.topic: t.msgtype for t in s.topics() if t.topic in topics}
            assert set(types) == topics
            fast = s.read_many([(t, None) for t in sorted(topics)])
            slow = s.read_many([(t, None) for t in sorted(topics)], fast=False)
        for a, b in zip(fast, slow, strict=True):
            assert (a.decoder, b.decoder) == ("numpy", "deserializer") and len(a) > 2000
            for attr in ("header_ns", "log_ns", "position", "orientation", "velocity",
                         "pose_var", "twist_var"):  # fmt: skip
                np.testing.assert_array_equal(getattr(a, attr), getattr(b, attr), err_msg=attr)
            assert (a.frame_id, a.child_frame_id) == (b.frame_id, b.child_frame_id)
        listed = open_rosbag2(dst)
        assert listed is not None
        batches = list(
            sqlite_batches(listed.files, sorted(topics), [types[t] for t in sorted(topics)])
        )
        assert {int(b.conn[0]) for b in batches} == set(range(len(topics)))
        assert all(b.trimmed for b in batches)
        assert set(np.concatenate([b.ends - b.starts for b in batches]).tolist()) == {size}
