"""``qsls ingest`` of PX4 ULogs (docs/ingest.md#px4-ulog): a flight written with the project's
ULog writer, its VIO in an FRD world of its own (yaw and offset), its truth the mocap
topic without velocity, both on the log's one clock; and bad input, each one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from qsls.cli.main import app
from qsls.pipeline.core.rotations import frd_ned_to_flu_enu, ned_to_enu, quat_to_matrix, rot_z
from qsls.pipeline.ingest.sources.text.writer import tum_text
from qsls.pipeline.ingest.sources.ulog.writer import Topic
from qsls.pipeline.ingest.streams import read_vio_stream
from tests.bagfixtures import truth_state
from tests.test_ulog import local_position, odometry, write, write_in_order, xyzw_to_wxyz

runner = CliRunner()
YAW0 = np.radians(25.0)
"""The VIO's FRD world: NED turned by this about z (down), and shifted by ``T0``."""
T0 = np.array([1.0, -2.0, 0.5])
DROPOUT = (12.0, 12.6)
START_US = 3_000_000


def _flight_topics(duration: float = 20.0, seed: int = 0) -> tuple[Topic, Topic]:
    """VIO (``vehicle_visual_odometry``, 50 Hz, pose in its FRD world, velocity BODY_FRD,
    ``DROPOUT`` missing) and truth (``vehicle_mocap_odometry``, 100 Hz, NED, no velocity)."""
    rng = np.random.default_rng(seed)

    def state(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        p, v, q = truth_state(t)  # ENU, FLU in ENU [x y z w]
        q_ned = xyzw_to_wxyz(frd_ned_to_flu_enu(q))  # the map is its own inverse
        return ned_to_enu(p), ned_to_enu(v), q_ned

    tv = np.arange(0.0, duration, 0.02)
    tv = tv[(tv < DROPOUT[0]) | (tv > DROPOUT[1])]
    p, v, q = state(tv)
    r0 = rot_z(YAW0)  # NED <- VIO's FRD world
    p_vio = (p - T0) @ r0 + rng.normal(scale=0.002, size=p.shape)
    r_b = quat_to_matrix(np.concatenate([q[:, 1:], q[:, :1]], axis=1))  # NED <- FRD body
    q_vio = xyzw_to_wxyz(_quat(r0.T[None] @ r_b))
    v_body = np.einsum("nji,nj->ni", r_b, v) + rng.normal(scale=0.01, size=v.shape)
    us = START_US + np.round(tv * 1e6).astype(np.int64)
    vio = odometry(
        "vehicle_visual_odometry", us + 3_000, p_vio, q_vio, v_body,
        pose_frame=2, velocity_frame=3, sample_us=us,
    )  # fmt: skip
    tt = np.arange(0.0, duration, 0.01)
    pt, _, qt = state(tt)
    ut = START_US + np.round(tt * 1e6).astype(np.int64)
    truth = odometry(
        "vehicle_mocap_odometry", ut + 1_000, pt, qt, np.full_like(pt, np.nan), sample_us=ut
    )
    return vio, truth


def _quat(m: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(m).as_quat()


@pytest.fixture(scope="module")
def flight_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    vio, truth = _flight_topics()
    d = tmp_path_factory.mktemp("ulog")
    drop_us = START_US + int(DROPOUT[0] * 1e6)
    return write(d / "flight.ulg", vio, truth, dropouts=[(drop_us, 600)], start_us=0)


def _ok(args: list[str], out: Path) -> dict:
    res = runner.invoke(app, ["ingest", *args, "--out", str(out)])
    assert res.exit_code == 0, res.output
    return json.loads((out / "manifest.json").read_text())["results"]


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
    return text


# --------------------------------------------------------------------------- ingest
def test_ingest_a_ulog(tmp_path: Path, flight_log: Path) -> None:
    """The defaults (``vehicle_visual_odometry`` against ``vehicle_mocap_odometry``): the
    clock offset is ~0 (one clock), the alignment undoes the VIO's world (ENU yaw
    ``-YAW0``: a turn about NED's down axis is the opposite turn about ENU's up), errors are
    the noise's, the dropout is a gap, and the VIO's logged (body-frame) velocity is used."""
    r = _ok([str(flight_log)], tmp_path / "o")
    assert abs(r["time_offset_s"]) < 0.002
    assert r["alignment"]["yaw_rad"] == pytest.approx(-YAW0, abs=np.radians(0.2))
    assert r["rms_position_m"] < 0.006
    assert r["rms_velocity_mps"] < 0.03
    s = r["streams"]
    assert s["vio"]["msgtype"] == s["truth"]["msgtype"] == "px4/vehicle_odometry"
    assert (s["vio"]["topic"], s["truth"]["topic"]) == (
        "vehicle_visual_odometry",
        "vehicle_mocap_odometry",
    )
    assert s["vio"]["decoder"] == "pyulog" and s["vio"]["rate_hz"] == pytest.approx(50.0)
    assert r["velocity_source"]["vio"].startswith("message twist")
    (gap,) = r["gaps"]
    assert gap["stream"] == "vio" and 0.6 < gap["duration_s"] < 0.65
    assert gap["start_ns"] == (START_US + 11_980_000) * 1000  # the last sample before it


def test_velocity_frame_option_does_not_rotate_a_ulog_velocity(
    tmp_path: Path, flight_log: Path
) -> None:
    """The ULog's velocity is world-frame whatever ``--vio-velocity-frame`` says."""
    _ok([str(flight_log)], tmp_path / "body")
    _ok([str(flight_log), "--vio-velocity-frame", "world"], tmp_path / "world")
    a = pq.read_table(tmp_path / "body" / "flight.parquet").to_pandas()
    b = pq.read_table(tmp_path / "world" / "flight.parquet").to_pandas()
    assert list(a.columns) == list(b.columns) and len(a) == len(b)
    np.testing.assert_allclose(a.to_numpy(), b.to_numpy(), atol=1e-9)


def test_ulog_given_as_vio_and_truth_files(tmp_path: Path, flight_log: Path) -> None:
    whole = _ok([str(flight_log)], tmp_path / "a")
    both = _ok(["--vio", str(flight_log), "--truth", str(flight_log)], tmp_path / "b")
    assert both["rms_position_m"] == whole["rms_position_m"]
    a = (tmp_path / "a" / "flight.parquet").read_bytes()
    assert a == (tmp_path / "b" / "flight.parquet").read_bytes()
    # the truth from another log, named with --truth-topic NAME:INSTANCE; the VIO a TUM file
    _, truth = _flight_topics()
    moved = Topic("vehicle_mocap_odometry", truth.fields, truth.data, multi_id=1)
    other = write(tmp_path / "truth.ulg", moved)
    tr = read_vio_stream(flight_log, None)
    (tmp_path / "vio.tum").write_text(tum_text(tr.header_ns, tr.position, tr.orientation))
    r = _ok(
        ["--vio", str(tmp_path / "vio.tum"), "--truth", str(other),
         "--truth-topic", "vehicle_mocap_odometry:1"],
        tmp_path / "c",
    )  # fmt: skip
    assert r["streams"]["truth"]["topic"] == "vehicle_mocap_odometry:1"
    assert r["rms_position_m"] < 0.006


# --------------------------------------------------------------------------- bad input
def test_missing_topics_list_what_the_log_has(tmp_path: Path) -> None:
    n = 30
    t = 1_000_000 + 10_000 * np.arange(n)
    lp = local_position(
        "vehicle_local_position", t, np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n)
    )
    log = write(tmp_path / "lp.ulg", lp)
    _fails(
        tmp_path, [str(log)], "no topic vehicle_visual_odometry",
        "vehicle_local_position (30 msgs)", "SDLOG_PROFILE bit 7", "logger_topics.txt",
        "--vio-topic",
    )  # fmt: skip


def test_unknown_and_wrong_topics(tmp_path: Path, flight_log: Path) -> None:
    _fails(
        tmp_path, [str(flight_log), "--vio-topic", "vins_odometry"], "no topic vins_odometry",
        "vehicle_visual_odometry (", "vehicle_mocap_odometry (",
    )  # fmt: skip
    _fails(
        tmp_path, [str(flight_log), "--truth-topic", "vehicle_mocap_odometry:x"], "NAME:INSTANCE"
    )
    _fails(
        tmp_path, [str(flight_log), "--truth-topic", "vehicle_visual_odometry"],
        "the VIO and truth streams are the same",
    )  # fmt: skip
    n = 20
    t = 1_000_000 + 10_000 * np.arange(n)
    att = Topic(
        "vehicle_attitude", [("uint64_t", "timestamp"), ("float[4]", "q")], {"timestamp": t}
    )
    log = write(tmp_path / "att.ulg", att)
    _fails(
        tmp_path,
        [str(log), "--vio-topic", "vehicle_attitude"],
        "not an odometry or local position topic",
    )


def test_truncated_and_damaged_ulog(tmp_path: Path, flight_log: Path) -> None:
    data = flight_log.read_bytes()
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(data[: len(data) // 2 + 1])
    _fails(tmp_path, [str(cut)], "truncated", "copy the log again")
    bad = tmp_path / "bad.ulg"
    bad.write_bytes(data[:16] + np.random.default_rng(0).bytes(4000))
    _fails(tmp_path, [str(bad)], "damaged")


def test_clock_jump(tmp_path: Path) -> None:
    vio, _ = _flight_topics(duration=8.0)
    k = 200
    first = Topic(vio.name, vio.fields, {n: np.asarray(a)[:k] for n, a in vio.data.items()})
    rest = {n: np.asarray(a)[k:] for n, a in vio.data.items()}
    rest["timestamp"] = rest["timestamp"] - 3_000_000  # the clock reset by 3 s
    log = write_in_order(tmp_path / "jump.ulg", first, Topic(vio.name, vio.fields, rest))
    _fails(
        tmp_path, ["--vio", str(log), "--truth", str(log), "--vio-topic", "vehicle_visual_odometry",
                   "--truth-topic", "vehicle_visual_odometry"],
        "vehicle_visual_odometry's timestamp jumps back 2.98 s", "use a log of one boot",
    )  # fmt: skip


def test_ulog_among_several_sources(tmp_path: Path, flight_log: Path) -> None:
    _fails(tmp_path, [str(flight_log), str(flight_log)], "a PX4 ULog among several sources")
