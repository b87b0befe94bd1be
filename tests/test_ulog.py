"""PX4 ULog reading: frame conversions by hand, synthetic logs of both field generations
written with the project's writer and read back with known values (docs/ingest.md#px4-ulog).

The helpers here (``odometry``, ``local_position``, ...) build the topics as PX4 defines them;
tests/test_ulog_cli.py and benchmarks/bench_ulog.py write their logs with them too.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.rotations import (
    Q_ENU_NED,
    Q_FRD_FLU,
    frd_ned_to_flu_enu,
    frd_to_flu,
    ned_to_enu,
    quat_mul,
    quat_to_matrix,
    world_to_body,
    wxyz_to_xyzw,
    yaw_ned_to_enu,
    yaw_quat,
)
from qsls.pipeline.ingest.sources.base import detect
from qsls.pipeline.ingest.sources.ulog.reader import (
    parse_topic,
    read_commands,
    read_odometry,
    read_setpoints,
    ulog_info,
    ulog_topics,
)
from qsls.pipeline.ingest.sources.ulog.writer import LogContent, Topic, write_ulog

S = np.sqrt(0.5)


# --------------------------------------------------------------------------- topic builders
def xyzw_to_wxyz(q: np.ndarray) -> np.ndarray:
    return np.concatenate([q[..., 3:4], q[..., :3]], axis=-1)


def q_ned_of_yaw_pitch(yaw: np.ndarray, pitch: np.ndarray | float = 0.0) -> np.ndarray:
    """PX4 quaternions ``[w, x, y, z]`` of an FRD body in NED at ``yaw`` (from north,
    clockwise) then ``pitch`` (nose up), ZYX order."""
    yaw = np.asarray(yaw, float)
    pitch = np.broadcast_to(np.asarray(pitch, float), yaw.shape)
    cy, sy, cp, sp = np.cos(yaw / 2), np.sin(yaw / 2), np.cos(pitch / 2), np.sin(pitch / 2)
    return np.stack([cy * cp, -sy * sp, cy * sp, sy * cp], axis=-1)


def odometry(
    name: str,
    t_us: np.ndarray,
    p_ned: np.ndarray,
    q_wxyz: np.ndarray,
    v: np.ndarray,
    *,
    generation: str = "new",
    pose_frame: int | np.ndarray | None = None,
    velocity_frame: int | np.ndarray | None = None,
    sample_us: np.ndarray | None = None,
    multi_id: int = 0,
) -> Topic:
    """A ``vehicle_odometry``-format topic; ``generation`` ``new`` (PX4 >= 1.14) or ``old``
    (``x, y, z``, ``local_frame``); frames default to NED."""
    n = len(t_us)
    t_us = np.asarray(t_us, np.uint64)
    ts = t_us if sample_us is None else np.asarray(sample_us, np.uint64)
    if generation == "new":
        fields = [
            ("uint64_t", "timestamp"), ("uint64_t", "timestamp_sample"),
            ("uint8_t", "pose_frame"), ("float[3]", "position"), ("float[4]", "q"),
            ("uint8_t", "velocity_frame"), ("float[3]", "velocity"),
            ("float[3]", "angular_velocity"), ("float[3]", "position_variance"),
            ("float[3]", "orientation_variance"), ("float[3]", "velocity_variance"),
            ("uint8_t", "reset_counter"), ("int8_t", "quality"),
        ]  # fmt: skip
        data = {
            "timestamp": t_us, "timestamp_sample": ts,
            "pose_frame": np.broadcast_to(1 if pose_frame is None else pose_frame, (n,)),
            "position": p_ned, "q": q_wxyz,
            "velocity_frame": np.broadcast_to(1 if velocity_frame is None else velocity_frame, (n,)),
            "velocity": v,
        }  # fmt: skip
    else:
        fields = [
            ("uint64_t", "timestamp"), ("uint64_t", "timestamp_sample"),
            ("float", "x"), ("float", "y"), ("float", "z"), ("float[4]", "q"),
            ("float[4]", "q_offset"), ("float[21]", "pose_covariance"),
            ("float", "vx"), ("float", "vy"), ("float", "vz"), ("float", "rollspeed"),
            ("float", "pitchspeed"), ("float", "yawspeed"),
            ("float[21]", "velocity_covariance"), ("uint8_t", "local_frame"),
            ("uint8_t", "velocity_frame"), ("uint8_t", "reset_counter"),
        ]  # fmt: skip
        p, vv = np.asarray(p_ned, float), np.asarray(v, float)
        data = {
            "timestamp": t_us, "timestamp_sample": ts,
            "x": p[:, 0], "y": p[:, 1], "z": p[:, 2], "q": q_wxyz,
            "vx": vv[:, 0], "vy": vv[:, 1], "vz": vv[:, 2],
            "local_frame": np.broadcast_to(0 if pose_frame is None else pose_frame, (n,)),
            "velocity_frame": np.broadcast_to(0 if velocity_frame is None else velocity_frame, (n,)),
        }  # fmt: skip
    return Topic(name, fields, data, multi_id)


def local_position(
    name: str,
    t_us: np.ndarray,
    p_ned: np.ndarray,
    v_ned: np.ndarray,
    heading: np.ndarray,
    *,
    generation: str = "new",
    sample_us: np.ndarray | None = None,
) -> Topic:
    """A ``vehicle_local_position``-format topic: ``new`` (``timestamp_sample``, ``heading``)
    or ``old`` (no ``timestamp_sample``, ``yaw``)."""
    t_us = np.asarray(t_us, np.uint64)
    p, v = np.asarray(p_ned, float), np.asarray(v_ned, float)
    cols = {"x": p[:, 0], "y": p[:, 1], "z": p[:, 2], "vx": v[:, 0], "vy": v[:, 1], "vz": v[:, 2]}
    head = [("uint64_t", "timestamp")]
    data: dict[str, np.ndarray] = {"timestamp": t_us}
    if generation == "new":
        head.append(("uint64_t", "timestamp_sample"))
        data["timestamp_sample"] = t_us if sample_us is None else np.asarray(sample_us, np.uint64)
    fields = [*head, ("uint64_t", "ref_timestamp"), *[("float", k) for k in cols]]
    yaw_name = "heading" if generation == "new" else "yaw"
    fields += [("float", yaw_name), ("bool", "xy_valid")]
    extra = {yaw_name: heading, "xy_valid": np.ones(len(t_us))}
    return Topic(name, fields, {**data, **cols, **extra})


def attitude(name: str, t_us: np.ndarray, q_wxyz: np.ndarray) -> Topic:
    t_us = np.asarray(t_us, np.uint64)
    fields = [("uint64_t", "timestamp"), ("uint64_t", "timestamp_sample"), ("float[4]", "q")]
    return Topic(name, fields, {"timestamp": t_us, "timestamp_sample": t_us, "q": q_wxyz})


def attitude_setpoint(
    t_us: np.ndarray, q_d_wxyz: np.ndarray, thrust: np.ndarray, *, generation: str = "new"
) -> Topic:
    """``vehicle_attitude_setpoint``: ``thrust`` (n, 3) ``thrust_body`` (new) or (n,) the
    scalar ``thrust`` (old)."""
    t_us = np.asarray(t_us, np.uint64)
    head = [("uint64_t", "timestamp"), ("float", "roll_body"), ("float", "pitch_body")]
    head += [("float", "yaw_body"), ("float[4]", "q_d")]
    if generation == "new":
        fields = [*head, ("float[3]", "thrust_body"), ("bool", "reset_integral")]
        data = {"timestamp": t_us, "q_d": q_d_wxyz, "thrust_body": thrust}
    else:
        fields = [*head, ("float", "thrust"), ("bool", "q_d_valid")]
        data = {"timestamp": t_us, "q_d": q_d_wxyz, "thrust": thrust}
        data["q_d_valid"] = np.ones(len(t_us))
    return Topic("vehicle_attitude_setpoint", [*fields], data)


def hover_estimate(t_us: np.ndarray, hover: np.ndarray, valid: np.ndarray) -> Topic:
    t_us = np.asarray(t_us, np.uint64)
    fields = [
        ("uint64_t", "timestamp"), ("uint64_t", "timestamp_sample"), ("float", "hover_thrust"),
        ("float", "hover_thrust_var"), ("bool", "valid"),
    ]  # fmt: skip
    data = {"timestamp": t_us, "timestamp_sample": t_us, "hover_thrust": hover, "valid": valid}
    return Topic("hover_thrust_estimate", fields, data)


def trajectory_setpoint(
    t_us: np.ndarray,
    p: np.ndarray,
    v: np.ndarray,
    a: np.ndarray,
    yaw: np.ndarray,
    *,
    generation: str = "new",
) -> Topic:
    """``trajectory_setpoint`` (NED): ``new`` (``position[3]``..), ``old`` (``x, y, z``,
    ``vx..``, ``acceleration[3]``) or ``oldest`` (``acc_x..``)."""
    t_us = np.asarray(t_us, np.uint64)
    if generation == "new":
        fields = [
            ("uint64_t", "timestamp"), ("float[3]", "position"), ("float[3]", "velocity"),
            ("float[3]", "acceleration"), ("float[3]", "jerk"), ("float", "yaw"),
            ("float", "yawspeed"),
        ]  # fmt: skip
        data = {"timestamp": t_us, "position": p, "velocity": v, "acceleration": a, "yaw": yaw}
        return Topic("trajectory_setpoint", fields, data)
    cols = {"x": p[:, 0], "y": p[:, 1], "z": p[:, 2], "yaw": yaw}
    cols |= {"vx": v[:, 0], "vy": v[:, 1], "vz": v[:, 2]}
    fields = [("uint64_t", "timestamp"), *[("float", k) for k in cols]]
    if generation == "old":
        fields.append(("float[3]", "acceleration"))
        cols["acceleration"] = a
    else:
        fields += [("float", "acc_x"), ("float", "acc_y"), ("float", "acc_z")]
        cols |= {"acc_x": a[:, 0], "acc_y": a[:, 1], "acc_z": a[:, 2]}
    return Topic("trajectory_setpoint", fields, {"timestamp": t_us, **cols})


def write(path: Path, *topics: Topic, **kw) -> Path:
    return write_ulog(path, LogContent(list(topics), **kw))


def write_in_order(path: Path, before: Topic, after: Topic) -> Path:
    """One topic's messages ``before`` then ``after`` in that order in the file, whatever
    their timestamps (the writer merges by timestamp: a clock reset needs this)."""
    from qsls.pipeline.ingest.sources.ulog.writer import ulog_bytes

    def rows(t: Topic, k: int) -> Topic:
        return Topic(t.name, t.fields, {n: np.asarray(a)[:k] for n, a in t.data.items()})

    prefix = len(ulog_bytes(LogContent([rows(before, 0)])))
    a, b = ulog_bytes(LogContent([before])), ulog_bytes(LogContent([after]))
    assert a[:prefix] == b[:prefix]
    path.write_bytes(a + b[prefix:])
    return path


def f32(x) -> np.ndarray:
    """What a float field stores."""
    return np.asarray(x, dtype=np.float32).astype(float)


# --------------------------------------------------------------------------- frames by hand
def test_ned_enu_positions_and_frd_flu_vectors() -> None:
    np.testing.assert_array_equal(ned_to_enu(np.array([1.0, 2.0, 3.0])), [2.0, 1.0, -3.0])
    # north 1 m, east 2 m, 3 m below the origin: east 2, north 1, up -3
    v = np.array([[1.0, 2.0, 3.0], [-4.0, 5.0, -6.0]])
    np.testing.assert_array_equal(ned_to_enu(ned_to_enu(v)), v)  # its own inverse
    np.testing.assert_array_equal(frd_to_flu(np.array([1.0, 2.0, 3.0])), [1.0, -2.0, -3.0])
    np.testing.assert_array_equal(wxyz_to_xyzw(np.array([1.0, 2, 3, 4])), [2.0, 3, 4, 1])


def test_quaternion_conversion_is_the_frame_product() -> None:
    """``q_enu_flu = q(ENU<-NED) q_ned_frd q(FRD<-FLU)``, as rotation matrices ``P R D``."""
    rng = np.random.default_rng(3)
    q = rng.normal(size=(50, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    got = frd_ned_to_flu_enu(q)
    n = len(q)
    prod = quat_mul(quat_mul(np.tile(Q_ENU_NED, (n, 1)), q), np.tile(Q_FRD_FLU, (n, 1)))
    np.testing.assert_allclose(np.abs(np.sum(got * prod, axis=1)), 1.0, atol=1e-12)
    P = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])
    D = np.diag([1.0, -1.0, -1.0])
    np.testing.assert_allclose(quat_to_matrix(got), P @ quat_to_matrix(q) @ D, atol=1e-12)
    np.testing.assert_allclose(frd_ned_to_flu_enu(got), q, atol=1e-15)  # an involution


def test_yaw_north_and_east() -> None:
    """A vehicle heading north (NED yaw 0) has ENU yaw pi/2; NED yaw 90 deg (east) is ENU 0."""
    assert yaw_ned_to_enu(np.array(0.0)) == pytest.approx(np.pi / 2)
    assert yaw_ned_to_enu(np.array(np.pi / 2)) == pytest.approx(0.0)
    assert yaw_ned_to_enu(np.array(np.pi)) == pytest.approx(-np.pi / 2)
    north = frd_ned_to_flu_enu(np.array([0.0, 0.0, 0.0, 1.0]))  # identity in NED
    np.testing.assert_allclose(north, [0.0, 0.0, S, S], atol=1e-15)  # 90 deg about z up
    east = frd_ned_to_flu_enu(wxyz_to_xyzw(q_ned_of_yaw_pitch(np.array(np.pi / 2))))
    np.testing.assert_allclose(quat_to_matrix(east), np.eye(3), atol=1e-12)  # ENU yaw 0
    np.testing.assert_allclose(yaw_quat(np.array([np.pi / 2])), [[0, 0, S, S]], atol=1e-15)


def test_pitch_up() -> None:
    """Nose up 30 deg heading north: the FLU x axis in ENU is (0, cos 30, sin 30), its z axis
    (up through the roof) leans back south: (0, -sin 30, cos 30)."""
    th = np.radians(30.0)
    q = frd_ned_to_flu_enu(wxyz_to_xyzw(q_ned_of_yaw_pitch(np.array([0.0]), th)))
    r = quat_to_matrix(q)[0]
    np.testing.assert_allclose(r[:, 0], [0.0, np.cos(th), np.sin(th)], atol=1e-12)
    np.testing.assert_allclose(r[:, 2], [0.0, -np.sin(th), np.cos(th)], atol=1e-12)


# --------------------------------------------------------------------------- odometry
@pytest.mark.parametrize("generation", ["new", "old"])
def test_odometry_known_values(tmp_path: Path, generation: str) -> None:
    n = 40
    t = 1_000_000 + 10_000 * np.arange(n)
    p = np.column_stack([np.arange(n) * 0.5, np.full(n, -1.25), np.full(n, -2.0)])  # 2 m up
    yaw = np.full(n, np.pi / 2)  # heading east
    q = q_ned_of_yaw_pitch(yaw)
    v = np.tile([1.0, 2.0, -0.5], (n, 1))  # NED: 1 north, 2 east, 0.5 up
    log = write(
        tmp_path / "a.ulg",
        odometry("vehicle_visual_odometry", t, p, q, v, generation=generation, sample_us=t - 700),
    )
    assert detect(log) == "ulog"
    tr = read_odometry(log, "vehicle_visual_odometry")
    assert tr.name == "vehicle_visual_odometry" and tr.msgtype == "px4/vehicle_odometry"
    assert tr.header_ns.dtype == np.int64 and tr.log_ns.dtype == np.int64
    np.testing.assert_array_equal(tr.log_ns, t * 1000)
    np.testing.assert_array_equal(tr.header_ns, (t - 700) * 1000)
    np.testing.assert_allclose(
        tr.position, np.column_stack([f32(p[:, 1]), f32(p[:, 0]), np.full(n, 2.0)])
    )
    np.testing.assert_allclose(
        quat_to_matrix(tr.orientation), np.tile(np.eye(3), (n, 1, 1)), atol=1e-6
    )
    assert tr.velocity is not None
    np.testing.assert_allclose(tr.velocity, np.tile([2.0, 1.0, 0.5], (n, 1)), atol=1e-6)


@pytest.mark.parametrize(("generation", "body_code"), [("new", 3), ("old", 3)])
def test_body_frame_velocity_is_rotated_to_the_world(
    tmp_path: Path, generation: str, body_code: int
) -> None:
    """Heading east, pitched 20 deg up, flying 2 m/s forward in FRD: in ENU that is
    (2 cos 20, 0, 2 sin 20); 1 m/s right in FRD is 1 m/s south."""
    n = 20
    t = 1_000_000 + 20_000 * np.arange(n)
    q = q_ned_of_yaw_pitch(np.full(n, np.pi / 2), np.radians(20.0))
    v_frd = np.tile([2.0, 1.0, 0.0], (n, 1))
    topic = odometry(
        "vehicle_mocap_odometry", t, np.zeros((n, 3)), q, v_frd,
        generation=generation, velocity_frame=body_code,
    )  # fmt: skip
    tr = read_odometry(write(tmp_path / "b.ulg", topic), "vehicle_mocap_odometry")
    th = np.radians(20.0)
    assert tr.velocity is not None
    np.testing.assert_allclose(
        tr.velocity, np.tile([2 * np.cos(th), -1.0, 2 * np.sin(th)], (n, 1)), atol=1e-6
    )


def test_frames_per_message_frd_world_unknown_and_nan_velocity(tmp_path: Path) -> None:
    n = 12
    t = 1_000_000 + 10_000 * np.arange(n)
    p = np.tile([1.0, 2.0, -3.0], (n, 1))
    q = q_ned_of_yaw_pitch(np.zeros(n))
    v = np.tile([1.0, 0.0, 0.0], (n, 1))
    vf = np.array([1, 2, 0] * 4)  # NED, FRD (world: as NED), unknown (NaN)
    log = write(
        tmp_path / "c.ulg",
        odometry("vehicle_visual_odometry", t, p, q, v, pose_frame=2, velocity_frame=vf),
    )
    tr = read_odometry(log, "vehicle_visual_odometry")
    np.testing.assert_allclose(tr.position, np.tile([2.0, 1.0, 3.0], (n, 1)))  # FRD as NED
    assert "FRD" in tr.frame_id
    assert tr.velocity is not None
    np.testing.assert_allclose(tr.velocity[vf != 0], np.tile([0.0, 1.0, 0.0], (8, 1)))
    assert np.isnan(tr.velocity[vf == 0]).all()
    # mocap without velocity: NaN throughout -> None (ingest differentiates the positions)
    nan_v = np.full((n, 3), np.nan)
    log = write(tmp_path / "d.ulg", odometry("vehicle_mocap_odometry", t, p, q, nan_v))
    assert read_odometry(log, "vehicle_mocap_odometry").velocity is None
    # a pose frame that is neither NED nor FRD is refused
    log = write(tmp_path / "e.ulg", odometry("vehicle_visual_odometry", t, p, q, v, pose_frame=0))
    with pytest.raises(InputError, match="pose frame other than NED or FRD"):
        read_odometry(log, "vehicle_visual_odometry")


def test_instances(tmp_path: Path) -> None:
    n = 15
    t = 1_000_000 + 10_000 * np.arange(n)
    q = q_ned_of_yaw_pitch(np.zeros(n))
    a = odometry("estimator_odometry", t, np.zeros((n, 3)), q, np.zeros((n, 3)))
    b = odometry("estimator_odometry", t, np.ones((n, 3)), q, np.zeros((n, 3)), multi_id=1)
    log = write(tmp_path / "i.ulg", a, b)
    assert ulog_topics(log) == [("estimator_odometry", 0, n), ("estimator_odometry", 1, n)]
    tr = read_odometry(log, "estimator_odometry", 1)
    assert tr.name == "estimator_odometry:1"
    np.testing.assert_allclose(tr.position, np.tile([1.0, 1.0, -1.0], (n, 1)))
    assert parse_topic("estimator_odometry:1") == ("estimator_odometry", 1)
    assert parse_topic("/vehicle_visual_odometry") == ("vehicle_visual_odometry", 0)
    with pytest.raises(InputError, match="NAME:INSTANCE"):
        parse_topic("estimator_odometry:x")
    with pytest.raises(InputError, match=r"estimator_odometry:2.*estimator_odometry:1"):
        read_odometry(log, "estimator_odometry", 2)


@pytest.mark.parametrize("generation", ["new", "old"])
def test_local_position_with_and_without_attitude(tmp_path: Path, generation: str) -> None:
    """Orientation from ``vehicle_attitude`` at the nearest stamp (``vehicle_attitude_groundtruth``
    for a ``_groundtruth`` topic), else the yaw-only quaternion of the heading."""
    n = 30
    t = 2_000_000 + 10_000 * np.arange(n)
    p = np.column_stack([np.zeros(n), np.arange(n) * 0.1, np.full(n, -1.0)])
    v = np.tile([0.0, 1.0, 0.0], (n, 1))  # east
    heading = np.full(n, np.pi / 2)
    lp = local_position("vehicle_local_position", t, p, v, heading, generation=generation)
    lone = read_odometry(write(tmp_path / "l.ulg", lp), "vehicle_local_position")
    assert lone.msgtype == "px4/vehicle_local_position"
    np.testing.assert_allclose(lone.position[:, 0], f32(np.arange(n) * 0.1))
    np.testing.assert_allclose(lone.position[:, 2], 1.0)
    np.testing.assert_allclose(
        quat_to_matrix(lone.orientation), np.tile(np.eye(3), (n, 1, 1)), atol=1e-6
    )
    assert lone.velocity is not None
    np.testing.assert_allclose(lone.velocity, np.tile([1.0, 0.0, 0.0], (n, 1)))
    # attitude at twice the rate, offset by 3 ms: the nearest sample's quaternion
    ta = 2_000_000 + 3_000 + 5_000 * np.arange(2 * n)
    pitch = np.radians(np.arange(2 * n) * 1.0)
    att = attitude("vehicle_attitude", ta, q_ned_of_yaw_pitch(np.zeros(2 * n), pitch))
    gt = attitude(
        "vehicle_attitude_groundtruth", ta, q_ned_of_yaw_pitch(np.full(2 * n, np.pi), 0.0)
    )
    lpg = local_position(
        "vehicle_local_position_groundtruth", t, p, v, heading, generation=generation
    )
    log = write(tmp_path / "la.ulg", lp, lpg, att, gt)
    tr = read_odometry(log, "vehicle_local_position")
    nearest = np.abs(t[:, None] - ta[None, :]).argmin(axis=1)
    want = frd_ned_to_flu_enu(wxyz_to_xyzw(q_ned_of_yaw_pitch(np.zeros(n), pitch[nearest])))
    np.testing.assert_allclose(np.abs(np.sum(tr.orientation * want, axis=1)), 1.0, atol=1e-6)
    g = read_odometry(log, "vehicle_local_position_groundtruth")  # heading south
    np.testing.assert_allclose(
        quat_to_matrix(g.orientation)[:, :, 0], np.tile([0, -1.0, 0], (n, 1)), atol=1e-6
    )


def test_stamps_and_dropouts(tmp_path: Path) -> None:
    n = 50
    t = 5_000_000 + 10_000 * np.arange(n)
    t = np.concatenate([t[:20], t[30:]])  # 0.1 s missing, a dropout reported there
    q = q_ned_of_yaw_pitch(np.zeros(len(t)))
    topic = odometry("vehicle_visual_odometry", t, np.zeros((len(t), 3)), q, np.zeros((len(t), 3)))
    log = write(
        tmp_path / "s.ulg", topic, parameters={"MPC_THR_HOVER": 0.42, "SDLOG_PROFILE": 129},
        info={"sys_name": "PX4"}, dropouts=[(int(t[19]) + 1, 95)], start_us=4_000_000,
    )  # fmt: skip
    info = ulog_info(log)
    assert info["start_us"] == 4_000_000 and info["last_us"] == int(t[-1])
    assert info["parameters"]["SDLOG_PROFILE"] == 129
    assert info["parameters"]["MPC_THR_HOVER"] == pytest.approx(0.42)
    assert info["info"] == {"sys_name": "PX4"}
    assert info["dropouts"] == [(int(t[19]), 95)]


# --------------------------------------------------------------------------- commands
@pytest.mark.parametrize("generation", ["new", "old"])
def test_commands_thrust_and_attitude(tmp_path: Path, generation: str) -> None:
    n = 10
    t = 1_000_000 + 4_000 * np.arange(n)
    q = q_ned_of_yaw_pitch(np.linspace(0, 1, n), 0.1)
    if generation == "new":
        thrust = np.column_stack([np.full(n, 0.1), np.full(n, -0.2), -np.linspace(0.3, 0.7, n)])
        want = np.linalg.norm(f32(thrust), axis=1)
    else:
        thrust = np.linspace(0.3, 0.7, n)
        want = f32(thrust)
    log = write(
        tmp_path / "c.ulg", attitude_setpoint(t, q, thrust, generation=generation),
        parameters={"MPC_THR_HOVER": 0.5, "THR_MDL_FAC": 0.3},
    )  # fmt: skip
    c = read_commands(log)
    np.testing.assert_array_equal(c.t_ns, t * 1000)
    assert c.t_ns.dtype == np.int64
    np.testing.assert_allclose(c.thrust, want)
    np.testing.assert_allclose(
        np.abs(np.sum(c.q * frd_ned_to_flu_enu(wxyz_to_xyzw(f32(q))), axis=1)), 1.0
    )
    np.testing.assert_allclose(c.hover_thrust, 0.5)
    assert c.hover_source == "MPC_THR_HOVER" and c.thr_mdl_fac == pytest.approx(0.3)


def test_hover_thrust_selection(tmp_path: Path) -> None:
    """The latest valid estimate at or before each command, else the parameter, else NaN."""
    t = 1_000_000 + 100_000 * np.arange(8)  # commands at 1.0 .. 1.7 s
    q = q_ned_of_yaw_pitch(np.zeros(8))
    sp = attitude_setpoint(t, q, np.tile([0, 0, -0.5], (8, 1)))
    te = np.array([1_150_000, 1_250_000, 1_350_000, 1_550_000])
    he = np.array([0.31, 0.32, 0.33, 0.35])
    valid = np.array([False, True, False, True])  # the estimate at 1.35 s is invalid
    est = hover_estimate(te, he, valid)
    c = read_commands(write(tmp_path / "h.ulg", sp, est, parameters={"MPC_THR_HOVER": 0.6}))
    want = [0.6, 0.6, 0.6, 0.32, 0.32, 0.32, 0.35, 0.35]
    np.testing.assert_allclose(c.hover_thrust, f32(want))
    assert c.hover_source == "mixed" and c.thr_mdl_fac is None
    # no parameter: NaN before the first valid estimate
    c = read_commands(write(tmp_path / "h2.ulg", sp, est))
    np.testing.assert_allclose(c.hover_thrust, f32([np.nan] * 3 + want[3:]))
    assert c.hover_source == "hover_thrust_estimate"
    c = read_commands(write(tmp_path / "h3.ulg", sp, hover_estimate(te, he, np.zeros(4, bool))))
    assert np.isnan(c.hover_thrust).all() and c.hover_source == "none"


def test_commands_missing(tmp_path: Path) -> None:
    n = 12
    t = 1_000_000 + 10_000 * np.arange(n)
    lp = local_position(
        "vehicle_local_position", t, np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n)
    )
    log = write(tmp_path / "m.ulg", lp)
    with pytest.raises(InputError, match=r"no vehicle_attitude_setpoint.*must be logged"):
        read_commands(log)
    with pytest.raises(InputError, match=r"no trajectory_setpoint.*must be logged"):
        read_setpoints(log)


# --------------------------------------------------------------------------- setpoints
@pytest.mark.parametrize("generation", ["new", "old", "oldest"])
def test_setpoints(tmp_path: Path, generation: str) -> None:
    n = 6
    t = 1_000_000 + 20_000 * np.arange(n)
    p = np.column_stack([np.arange(n) * 1.0, np.full(n, 2.0), np.full(n, -1.5)])
    p[2, 0] = np.nan  # an axis left free
    v = np.tile([0.5, -0.25, 0.125], (n, 1))
    a = np.tile([0.0, 1.0, -9.0], (n, 1))
    yaw = np.array([0.0, np.pi / 2, np.pi, -np.pi / 2, np.nan, 0.25])
    log = write(tmp_path / "s.ulg", trajectory_setpoint(t, p, v, a, yaw, generation=generation))
    s = read_setpoints(log)
    np.testing.assert_array_equal(s.t_ns, t * 1000)
    np.testing.assert_allclose(s.p, np.column_stack([np.full(n, 2.0), p[:, 0], np.full(n, 1.5)]))
    assert np.isnan(s.p[2, 1]) and np.isfinite(s.p[2, [0, 2]]).all()
    np.testing.assert_allclose(s.v, np.tile([-0.25, 0.5, -0.125], (n, 1)))
    np.testing.assert_allclose(s.a, np.tile([1.0, 0.0, 9.0], (n, 1)))
    want = [np.pi / 2, 0.0, -np.pi / 2, -np.pi, np.nan, np.pi / 2 - f32(0.25)]
    np.testing.assert_allclose(s.yaw, want, atol=1e-6)


def test_clock_jump_is_refused(tmp_path: Path) -> None:
    n = 40
    t = 10_000_000 + 10_000 * np.arange(n)
    t[25:] -= 2_000_000  # back 2 s
    q = q_ned_of_yaw_pitch(np.zeros(n))

    def odo(rows: slice, stamps: np.ndarray) -> Topic:
        z = np.zeros((n, 3))[rows]
        return odometry("vehicle_visual_odometry", stamps[rows], z, q[rows], z)

    log = write_in_order(tmp_path / "j.ulg", odo(slice(0, 25), t), odo(slice(25, n), t))
    with pytest.raises(
        InputError, match=r"vehicle_visual_odometry's timestamp jumps back 1\.99 s at 10\.240 s"
    ):
        read_odometry(log, "vehicle_visual_odometry")
    # a small step back (under 0.25 s) is read as it is (ingest sorts it)
    t2 = 10_000_000 + 10_000 * np.arange(n)
    t2[25:] -= 200_000
    log = write_in_order(tmp_path / "k.ulg", odo(slice(0, 25), t2), odo(slice(25, n), t2))
    tr = read_odometry(log, "vehicle_visual_odometry")
    np.testing.assert_array_equal(tr.log_ns, t2 * 1000)


def test_prepare_takes_a_ulog_velocity_as_world(tmp_path: Path) -> None:
    """Ingest's velocity step rotates a ``body`` twist by the orientation; a ULog stream's
    velocity is world-frame already: the VIO's is handed over in the body frame so the step
    gives it back, and one with NaN on some messages is differentiated instead."""
    from qsls.pipeline.ingest.options import IngestOptions
    from qsls.pipeline.ingest.streams import prepare
    from qsls.pipeline.ingest.velocity import vio_velocity

    n = 200
    t = 1_000_000 + 10_000 * np.arange(n)
    tt = (t - t[0]) * 1e-6
    p = np.column_stack([np.sin(tt), np.cos(tt), -tt])
    v = np.column_stack([np.cos(tt), -np.sin(tt), -np.ones(n)])
    q = q_ned_of_yaw_pitch(tt, 0.2)
    log = write(tmp_path / "v.ulg", odometry("vehicle_visual_odometry", t, p, q, v))
    traj = read_odometry(log, "vehicle_visual_odometry")
    assert traj.velocity is not None
    want = traj.velocity.copy()
    for frame in ("body", "world"):
        o = IngestOptions(vio_velocity_frame=frame)
        pre = prepare(traj, "vio", str(log), o)
        if frame == "body":
            assert pre.velocity is not None
            body = world_to_body(traj.orientation, want)
            np.testing.assert_allclose(pre.velocity, body, atol=1e-12)
        got, _ = vio_velocity(pre, frame, 0.1, 0.25)  # (rotates a body twist in place)
        np.testing.assert_allclose(got, want, atol=1e-12)
    v[5] = np.nan
    log = write(tmp_path / "w.ulg", odometry("vehicle_visual_odometry", t, p, q, v))
    pre = prepare(read_odometry(log, "vehicle_visual_odometry"), "vio", str(log), IngestOptions())
    assert pre.velocity is None and pre.nonfinite == 0


def test_every_cut_is_refused_or_a_whole_shorter_log(tmp_path: Path, monkeypatch) -> None:
    """A file cut at a byte (each of the last 300, every 7th before): refused as truncated (or damaged), or, cut exactly between
    two messages, read as the shorter log it then is; the walk (blocks of 97 bytes) and
    pyulog over the whole file (:func:`.scan.load_whole`) agree on which."""
    from qsls.pipeline.ingest.sources.ulog import scan

    monkeypatch.setattr(scan, "BLOCK", 97)
    n = 6
    t = 1_000_000 + 10_000 * np.arange(n)
    q = q_ned_of_yaw_pitch(np.zeros(n))
    log = write(
        tmp_path / "w.ulg", odometry("vehicle_visual_odometry", t, np.zeros((n, 3)), q, np.zeros((n, 3))),
        parameters={"MPC_THR_HOVER": 0.5}, dropouts=[(int(t[2]) + 1, 20)],
    )  # fmt: skip
    data = log.read_bytes()
    cut = tmp_path / "c.ulg"
    whole = 0
    cuts = sorted({*range(17, len(data) - 300, 7), *range(len(data) - 300, len(data) + 1)})
    for k in cuts:
        cut.write_bytes(data[:k])
        outcomes = []
        for read in (scan.load, scan.load_whole):
            try:
                u = read(cut, ["vehicle_visual_odometry"])
                outcomes.append(sum(len(d.data["timestamp"]) for d in u.data_list))
            except InputError as e:
                assert "truncated" in str(e) or "damaged" in str(e)
                outcomes.append(-1)
        assert outcomes[0] == outcomes[1], k
        whole += outcomes[0] >= 0
    assert whole >= 3 and outcomes[0] == n  # the whole file reads whole
