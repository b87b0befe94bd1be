"""qsls ingest on known flights: recover the injected clock offset, frame and velocities."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from qsls.cli.main import app
from qsls.pipeline.ingest.flight import read_flight
from qsls.pipeline.ingest.sources.msgtypes import POSE_COV, TRANSFORM
from qsls.pipeline.ingest.sources.text.reader import read_tum
from qsls.pipeline.ingest.sources.write import FORMATS, write_bag
from qsls.pipeline.ingest.stage import IngestOptions, ingest
from tests.bagfixtures import T0_NS, bag_name, make_flight, tf_streams, truth_state, write_flight

runner = CliRunner()


def _check_truth_columns(df, tol_p: float = 2e-3, tol_v: float = 5e-3) -> None:
    """x_* are the analytic truth at the grid stamps (VIO clock = true time here)."""
    t = (df["stamp_ns"].to_numpy() - T0_NS) * 1e-9
    p, v, _ = truth_state(t)
    assert np.abs(df[["x_px", "x_py", "x_pz"]].to_numpy() - p).max() < tol_p
    assert np.abs(df[["x_vx", "x_vy", "x_vz"]].to_numpy() - v).max() < tol_v


@pytest.mark.parametrize("fmt", FORMATS)
def test_recovers_offset_yaw_and_velocity(tmp_path: Path, fmt: str) -> None:
    f = make_flight(offset_s=0.083, yaw_deg=37.0, seed=FORMATS.index(fmt))
    bag = write_flight(tmp_path / bag_name(fmt), fmt, f)
    r = ingest([bag], IngestOptions(), tmp_path / "out")
    assert abs(r.time_offset_s - f.offset_s) < 0.005
    assert abs(np.degrees(r.alignment["yaw_rad"]) - 37.0) < 0.5
    np.testing.assert_allclose(r.alignment["translation"], f.translation, atol=0.01)
    df = read_flight(tmp_path / "out")
    _check_truth_columns(df)
    # measurement = truth + noise (2 mm, 1 cm/s): the errors are that small
    assert r.rms_position_m < 0.01
    assert 0.005 < r.rms_velocity_mps < 0.04
    e = df[[c for c in df.columns if c.startswith("e_")]].to_numpy()
    np.testing.assert_allclose(e, df[[c.replace("e_", "y_") for c in df.columns if c.startswith("e_")]].to_numpy()
                               - df[[c.replace("e_", "x_") for c in df.columns if c.startswith("e_")]].to_numpy())  # fmt: skip
    # grid: dt = 0.1 s on the VIO clock, nothing inside the 0.6 s dropout
    st = df["stamp_ns"].to_numpy()
    assert np.all(st % 100_000_000 == 0)
    t = (st - T0_NS) * 1e-9
    assert not np.any((t > 12.0 + 1e-9) & (t < 12.6 - 1e-9))
    m = json.loads((tmp_path / "out" / "manifest.json").read_text())
    res = m["results"]
    assert res["time_offset_s"] == pytest.approx(r.time_offset_s)
    assert set(res["alignment"]) >= {"method", "rotation", "translation", "yaw_rad"}
    assert len(res["gaps"]) == 1 and res["gaps"][0]["stream"] == "vio"
    assert res["gaps"][0]["duration_s"] == pytest.approx(0.64, abs=1e-6)
    assert (
        "twist" in res["velocity_source"]["vio"]
        and "differentiator" in res["velocity_source"]["truth"]
    )
    assert res["streams"]["vio"]["decoder"] == "numpy"
    assert m["stage"] == "ingest" and m["options"]["align"] == "4dof"


def test_two_sources_se3_and_world_velocity(tmp_path: Path) -> None:
    """VIO and truth in two bags of different formats; a full 3-D rotation; world twist."""
    from scipy.spatial.transform import Rotation

    r0 = Rotation.from_euler("ZYX", [-120.0, 4.0, -3.0], degrees=True).as_matrix()
    f = make_flight(rotation=r0, offset_s=-0.21, velocity_frame="world", seed=3)
    vbag = write_bag(tmp_path / "vio", [f.vio], "ros2-mcap")
    tbag = write_bag(tmp_path / "mocap.bag", [f.truth], "ros1")
    o = IngestOptions(align="se3", vio_velocity_frame="world")
    r = ingest([vbag, tbag], o, tmp_path / "out")
    assert abs(r.time_offset_s - f.offset_s) < 0.005
    np.testing.assert_allclose(np.array(r.alignment["rotation"]), r0, atol=2e-3)
    assert r.rms_position_m < 0.01 and r.rms_velocity_mps < 0.04
    _check_truth_columns(read_flight(tmp_path / "out"))
    # 4dof cannot absorb the roll/pitch: a clearly larger error, but still the right yaw
    r4 = ingest([vbag, tbag], IngestOptions(vio_velocity_frame="world"), tmp_path / "out4")
    assert r4.rms_position_m > 3 * r.rms_position_m


@pytest.mark.parametrize(
    ("msgtype", "fmt"),
    [(POSE_COV, "ros2-sqlite"), (TRANSFORM, "mcap"), ("nav_msgs/msg/Odometry", "ros1")],
)
def test_truth_message_types(tmp_path: Path, msgtype: str, fmt: str) -> None:
    f = make_flight(truth_msgtype=msgtype, duration=15.0, dropouts=())
    bag = write_flight(tmp_path / bag_name(fmt), fmt, f)
    o = IngestOptions(vio_topic="/vio/odom", truth_topic="/mocap/pose", time_offset=0.083)
    r = ingest([bag], o, tmp_path / "out")
    assert r.time_offset_s == 0.083
    assert abs(np.degrees(r.alignment["yaw_rad"]) - 37.0) < 0.5
    _check_truth_columns(read_flight(tmp_path / "out"))


def test_tf_truth_and_cli(tmp_path: Path) -> None:
    f = make_flight(duration=15.0, dropouts=())
    t = f.truth
    tf1, tf2 = tf_streams(t, "imu", t.position * 0, 5)
    bag = write_bag(tmp_path / "tf.bag", [f.vio, tf1, tf2], "ros1")
    out = tmp_path / "out"
    res = runner.invoke(
        app,
        [
            "ingest",
            str(bag),
            "--truth-frame",
            "world/quad",
            "--out",
            str(out),
            "--export-tum",
            "--dt",
            "0.05",
        ],
    )
    assert res.exit_code == 0, res.output
    assert "RMS position error" in res.output
    df = read_flight(out)
    assert np.all(np.diff(df["stamp_ns"].to_numpy()) == 50_000_000)
    _check_truth_columns(df)
    m = json.loads((out / "manifest.json").read_text())
    assert abs(m["results"]["time_offset_s"] - f.offset_s) < 0.005
    # the TUM exports are the aligned trajectories on the VIO clock
    vt, tt = read_tum(out / "vio_aligned.tum"), read_tum(out / "truth.tum")
    np.testing.assert_array_equal(vt.header_ns, f.vio.header_ns)
    p, _, _ = truth_state((vt.header_ns - T0_NS) * 1e-9)
    assert np.abs(vt.position - p).max() < 0.02
    ptt, _, _ = truth_state((tt.header_ns - T0_NS) * 1e-9)
    assert np.abs(tt.position - ptt).max() < 1e-3  # truth shifted onto the VIO clock
    # the same again: refused without --force, byte-identical data with it
    again = runner.invoke(
        app, ["ingest", str(bag), "--truth-frame", "world/quad", "--out", str(out)]
    )
    assert again.exit_code != 0 and "--force" in again.output
    before = (out / "flight.parquet").read_bytes()
    cfg = tmp_path / "c.yaml"
    cfg.write_text("truth_frame: world/quad\ndt: 0.05\nexport_tum: true\n")
    forced = runner.invoke(
        app, ["ingest", str(bag), "--config", str(cfg), "--out", str(out), "--force"]
    )
    assert forced.exit_code == 0, forced.output
    assert (out / "flight.parquet").read_bytes() == before


def test_log_stamps_and_auto_choice(tmp_path: Path) -> None:
    """--stamp log uses the bag's receive times (here the header stamps are garbage)."""
    f = make_flight(duration=15.0, dropouts=(), offset_s=0.0)
    bad_hdr = np.zeros_like(f.vio.header_ns)
    from dataclasses import replace

    vio = replace(f.vio, header_ns=bad_hdr, log_ns=f.vio.header_ns)
    truth = replace(f.truth, header_ns=f.truth.header_ns * 0 + 5, log_ns=f.truth.header_ns)
    bag = write_bag(tmp_path / "b.mcap", [vio, truth], "mcap")
    r = ingest([bag], IngestOptions(stamp="log"), tmp_path / "out")
    assert abs(r.time_offset_s) < 0.005
    _check_truth_columns(read_flight(tmp_path / "out"))


def test_unsorted_and_duplicate_stamps_are_counted(tmp_path: Path) -> None:
    from dataclasses import replace

    f = make_flight(duration=15.0, dropouts=())
    h = f.vio.header_ns.copy()
    h[[100, 101]] = h[[101, 100]]  # two swapped (unsorted)
    dup = np.arange(200, 230, 10)
    h[dup + 1] = h[dup]  # three exact duplicates
    vio = replace(f.vio, header_ns=h)
    bag = write_bag(tmp_path / "b.bag", [vio, f.truth], "ros1")
    r = ingest([bag], IngestOptions(), tmp_path / "out")
    m = json.loads((tmp_path / "out" / "manifest.json").read_text())["results"]
    assert m["duplicates_dropped"] == {"vio": 3, "truth": 0}
    assert m["unsorted_stamps"]["vio"] == 1
    assert r.streams["vio"]["samples"] == len(h) - 3
    assert abs(r.time_offset_s - f.offset_s) < 0.005


def test_text_inputs_without_velocity(tmp_path: Path) -> None:
    """TUM files: VIO velocity from the smoothing differentiator, and the manifest says so."""
    f = make_flight(duration=20.0, dropouts=(), noise_m=0.0005)

    def tum(path: Path, ns, p, q) -> Path:
        path.write_text(
            "".join(
                f"{n // 10**9}.{n % 10**9:09d} {' '.join(f'{x:.12g}' for x in [*a, *b])}\n"
                for n, a, b in zip(ns, p, q, strict=True)
            )
        )
        return path

    v = tum(tmp_path / "est.txt", f.vio.header_ns, f.vio.position, f.vio.orientation)
    g = tum(tmp_path / "gt.txt", f.truth.header_ns, f.truth.position, f.truth.orientation)
    res = runner.invoke(
        app, ["ingest", "--vio", str(v), "--truth", str(g), "--out", str(tmp_path / "o")]
    )
    assert res.exit_code == 0, res.output
    m = json.loads((tmp_path / "o" / "manifest.json").read_text())["results"]
    assert "differentiator" in m["velocity_source"]["vio"]
    assert abs(m["time_offset_s"] - f.offset_s) < 0.005
    assert m["rms_velocity_mps"] < 0.05


def test_truth_gap_listed_on_vio_clock(tmp_path: Path) -> None:
    from dataclasses import replace

    f = make_flight(duration=15.0, dropouts=())
    t = f.truth
    tt = (t.header_ns - T0_NS) * 1e-9 + f.offset_s  # true time
    keep = (tt < 6.0) | (tt > 6.5)
    truth = replace(
        t,
        header_ns=t.header_ns[keep],
        log_ns=t.log_ns[keep],
        position=t.position[keep],
        orientation=t.orientation[keep],
    )
    bag = write_bag(tmp_path / "g.bag", [f.vio, truth], "ros1")
    r = ingest([bag], IngestOptions(max_gap=0.3), tmp_path / "out")
    (gap,) = r.gaps
    assert gap["stream"] == "truth"
    assert abs((gap["start_ns"] - T0_NS) * 1e-9 - 6.0) < 0.011
    assert abs(gap["duration_s"] - 0.51) < 0.011
    st = (read_flight(tmp_path / "out")["stamp_ns"].to_numpy() - T0_NS) * 1e-9
    assert not np.any((st > 6.01) & (st < 6.49))
    assert np.any(np.isclose(st, 5.9)) and np.any(np.isclose(st, 6.6))


def _blas_threads() -> int:
    from threadpoolctl import threadpool_info

    return max(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas")


def test_blas_held_to_one_thread_while_ingest_hashes(tmp_path: Path) -> None:
    """The input hash runs on the second core while the bag is read and aligned; OpenBLAS's
    workers spin on that core after each threaded call, so BLAS gets one thread for the
    ingest, and its setting is given back afterwards, after a refused input too."""
    from threadpoolctl import threadpool_limits

    from qsls.pipeline.core.errors import InputError
    from qsls.pipeline.core.progress import NullProgress

    seen: list[int] = []

    class Watch(NullProgress):
        def advance(self, amount: float = 1.0) -> None:
            seen.append(_blas_threads())

    bag = write_flight(tmp_path / bag_name("ros2-mcap"), "ros2-mcap", make_flight(seed=3))
    with threadpool_limits(limits=2, user_api="blas"):
        if _blas_threads() < 2:
            pytest.skip("BLAS runs one thread here: nothing to hold back")
        ingest([bag], IngestOptions(), tmp_path / "out", progress=Watch())
        assert _blas_threads() == 2
        with pytest.raises(InputError, match="no topic"):
            ingest([bag], IngestOptions(vio_topic="/nope"), tmp_path / "o2", progress=Watch())
        assert _blas_threads() == 2
    assert seen and set(seen) == {1}
