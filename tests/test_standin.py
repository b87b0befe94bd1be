"""The PX4 stand-in (docs/simulation.md#the-px4-stand-in): the PX4 interface in the closed
loop, the estimate read by its arrival, and the ULog PX4 would write of the flight."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import yaml
from typer.testing import CliRunner

from qsls.cli.main import app
from qsls.pipeline.core.plant import GRAVITY
from qsls.pipeline.core.rotations import quat_to_matrix
from qsls.pipeline.export.attitude import thrust_attitude
from qsls.pipeline.export.cbuild import find_compiler
from qsls.pipeline.sim.closedloop import fly
from qsls.pipeline.sim.options import FlightOptions, SimOptions
from qsls.pipeline.sim.simulate import simulate
from qsls.pipeline.sim.ticks import TickLog
from tests.controllerfixtures import synthesized

pyulog = pytest.importorskip("pyulog")

BOOT_US = 20_000_000
LATENCY_S = 0.015
MASS = 0.256
BACKEND = "c" if find_compiler() else "python"
"""The exported C controller where a compiler is on PATH (as on the vehicle)."""
PX4 = {
    "interface": "px4",
    "estimator_latency_s": LATENCY_S,
    "estimator_jitter_s": 0.004,
    "estimator_drop": 0.05,
    "mocap_latency_s": 0.004,
    "mocap_jitter_s": 0.002,
    "mocap_drop": 0.01,
}
ODOMETRY = [
    ("uint64_t", 0, "timestamp"), ("uint64_t", 0, "timestamp_sample"), ("float", 3, "position"),
    ("float", 4, "q"), ("float", 3, "velocity"), ("float", 3, "angular_velocity"),
    ("float", 3, "position_variance"), ("float", 3, "orientation_variance"),
    ("float", 3, "velocity_variance"), ("uint8_t", 0, "pose_frame"),
    ("uint8_t", 0, "velocity_frame"), ("uint8_t", 0, "reset_counter"), ("int8_t", 0, "quality"),
]  # fmt: skip
FIELDS = {
    "vehicle_visual_odometry": ODOMETRY,
    "vehicle_mocap_odometry": ODOMETRY,
    "vehicle_attitude_setpoint": [
        ("uint64_t", 0, "timestamp"), ("float", 0, "roll_body"), ("float", 0, "pitch_body"),
        ("float", 0, "yaw_body"), ("float", 0, "yaw_sp_move_rate"), ("float", 4, "q_d"),
        ("float", 3, "thrust_body"), ("bool", 0, "reset_integral"),
        ("bool", 0, "fw_control_yaw_wheel"),
    ],
    "trajectory_setpoint": [
        ("uint64_t", 0, "timestamp"), ("float", 3, "position"), ("float", 3, "velocity"),
        ("float", 3, "acceleration"), ("float", 3, "jerk"), ("float", 0, "yaw"),
        ("float", 0, "yawspeed"),
    ],
    "hover_thrust_estimate": [
        ("uint64_t", 0, "timestamp"), ("uint64_t", 0, "timestamp_sample"),
        ("float", 0, "hover_thrust"), ("float", 0, "hover_thrust_var"),
        ("float", 0, "accel_innov"), ("float", 0, "accel_innov_var"),
        ("float", 0, "accel_innov_test_ratio"), ("float", 0, "accel_noise_var"),
        ("bool", 0, "valid"),
    ],
}  # fmt: skip


@pytest.fixture(scope="module")
def controller(tmp_path_factory):
    """A certified robust L1 controller (T = 8), written as ``qsls synth`` writes one."""
    return synthesized(T=8, calibrated=tmp_path_factory.mktemp("standin")).folder


@pytest.fixture(scope="module")
def flown(controller, tmp_path_factory):
    """A stand-in flight: the C controller, PX4 interface, latency, jitter and drops."""
    out = tmp_path_factory.mktemp("flown") / "sim"
    options = SimOptions.model_validate(
        {
            "controller": {"kind": str(controller), "backend": BACKEND},
            "log": {"format": "ulog"},
            "px4": PX4,
        }
    )
    res = simulate(options, out)
    return res, pyulog.ULog(str(res.bag))


def _topic(ulog, name):
    return ulog.get_dataset(name).data


def _vec(data, field, n):
    return np.column_stack([data[f"{field}[{i}]"] for i in range(n)]).astype(float)


def _ned_to_enu(v):
    return np.column_stack([v[:, 1], v[:, 0], -v[:, 2]])


def test_the_ulog_reads_back_with_pyulog_as_px4_writes_it(flown, controller):
    res, ulog = flown
    assert res.bag.name == "flight.ulg"
    assert ulog.start_timestamp == BOOT_US
    for name, fields in FIELDS.items():
        assert ulog.message_formats[name].fields == fields, name
        ts = _topic(ulog, name)["timestamp"]
        assert ts.dtype == np.uint64 and np.all(np.diff(ts.astype(np.int64)) >= 0), name
        assert ts[0] >= BOOT_US, name
    assert {d.name for d in ulog.data_list} == set(FIELDS) | {"vehicle_local_position"}
    assert ulog.initial_parameters == {
        "MPC_THR_HOVER": pytest.approx(0.5), "THR_MDL_FAC": 0.0, "SDLOG_PROFILE": 129
    }  # fmt: skip
    assert isinstance(ulog.initial_parameters["SDLOG_PROFILE"], int)
    cert = yaml.safe_load((controller / "certificate.yaml").read_text())
    assert ulog.msg_info_dict == {
        "sys_name": "qsls stand-in",
        "ver_sw": "qsls",
        "qsls_controller": "l1_robust",
        "qsls_controller_sha256": cert["controller_sha256"],
        "qsls_gate": "none",
    }
    # the setpoints: one per tick at the tick's time exactly, yaw east (NED pi / 2)
    ticks = TickLog.read(res.out)
    att = _topic(ulog, "vehicle_attitude_setpoint")
    tick_us = BOOT_US + np.round(ticks.t * 1e6).astype(np.int64)
    assert np.array_equal(att["timestamp"].astype(np.int64), tick_us)
    traj = _topic(ulog, "trajectory_setpoint")
    assert np.array_equal(traj["timestamp"], att["timestamp"])
    # (the export's minimal tilt has no twist about z: its ZYX yaw moves by second-order terms)
    assert np.allclose(traj["yaw"], np.pi / 2) and np.allclose(
        att["yaw_body"], np.pi / 2, atol=0.03
    )
    ref = ticks.ref
    assert np.allclose(_ned_to_enu(_vec(traj, "position", 3)), ref[:, :3], atol=1e-6)
    assert np.allclose(_ned_to_enu(_vec(traj, "velocity", 3)), ref[:, 3:], atol=1e-6)
    # odometry: captured before it arrived, NED frames, unit quaternions
    for name in ("vehicle_visual_odometry", "vehicle_mocap_odometry"):
        od = _topic(ulog, name)
        lag = od["timestamp"].astype(np.int64) - od["timestamp_sample"].astype(np.int64)
        assert (
            lag.min() >= 0 and np.all(od["pose_frame"] == 1) and np.all(od["velocity_frame"] == 1)
        )
        assert np.allclose(np.linalg.norm(_vec(od, "q", 4), axis=1), 1.0, atol=1e-6)
    vio = _topic(ulog, "vehicle_visual_odometry")
    lag = vio["timestamp"].astype(np.int64) - vio["timestamp_sample"].astype(np.int64)
    assert lag[1:].min() >= 15_000 and lag.max() <= 19_000 + 10_000  # latency + jitter (+ order)
    px4 = json.loads((res.out / "manifest.json").read_text())["results"]["px4"]
    assert px4["estimator"]["dropped"] > 0 and px4["mocap"]["dropped"] > 0
    assert len(vio["timestamp"]) == px4["estimator"]["samples"] - px4["estimator"]["dropped"]
    assert px4["hover_thrust"] == 0.5 and px4["controller_sha256"] == cert["controller_sha256"]
    # mocap: truth velocity (NED), the physics' true attitude within the mocap noise
    hover = _topic(ulog, "hover_thrust_estimate")
    assert np.allclose(hover["hover_thrust"], 0.5) and np.all(hover["valid"] == 1)
    assert np.all(np.diff(hover["timestamp"].astype(np.int64)) == 100_000)


def test_the_attitude_setpoint_is_the_exports_map_of_the_ticks_input(flown):
    """q_d back to the body z axis (ENU), times T m g / hover: the force the export's
    attitude map makes of the tick log's input (float32 apart)."""
    res, ulog = flown
    ticks = TickLog.read(res.out)
    att = _topic(ulog, "vehicle_attitude_setpoint")
    # the export's forward map of the absolute input: deviation and reference acceleration
    g = GRAVITY
    uff = ticks.uff
    acc = np.column_stack([-uff[:, 0] * g, uff[:, 1] * g, uff[:, 2] / MASS])
    dev = ticks.u - np.array([0.0, 0.0, MASS * g]) - uff
    thrust, q = thrust_attitude(dev, acc, MASS)
    want = quat_to_matrix(q)[:, :, 2] * thrust[:, None]
    # the log's: R(q_d) of the FRD body in NED, its up axis -z_FRD, NED -> ENU
    w, x, y, z = _vec(att, "q_d", 4).T
    qd = np.column_stack([x, y, z, w])
    up_ned = -quat_to_matrix(qd)[:, :, 2]
    t_sp = -_vec(att, "thrust_body", 3)[:, 2]
    assert np.allclose(_vec(att, "thrust_body", 3)[:, :2], 0.0)
    got = _ned_to_enu(up_ned) * (t_sp * MASS * g / 0.5)[:, None]
    err = np.abs(got - want).max()
    assert err < 2e-6 * np.abs(want).max(), err
    assert t_sp.min() > 0.35 and t_sp.max() < 0.7  # within the limits: nothing clipped
    assert np.abs(want[:, :2]).max() > 0.05  # and tilted: the check is not about hover alone


def test_every_tick_reads_the_newest_estimate_that_has_arrived(flown):
    """With latency L the controller's y at each tick is the newest vehicle_visual_odometry
    message with timestamp <= the tick (NED -> ENU, float32), never one still in flight."""
    res, ulog = flown
    ticks = TickLog.read(res.out)
    vio = _topic(ulog, "vehicle_visual_odometry")
    ts = vio["timestamp"].astype(np.int64)
    tick_us = BOOT_US + np.round(ticks.t * 1e6).astype(np.int64)
    idx = np.searchsorted(ts, tick_us, side="right") - 1
    assert idx.min() >= 0
    y = np.hstack([_ned_to_enu(_vec(vio, "position", 3)), _ned_to_enu(_vec(vio, "velocity", 3))])
    assert np.allclose(ticks.y, y[idx], rtol=1e-6, atol=2e-6)
    # and older than the newest capture: the latency shows at every tick but the first
    age = tick_us - vio["timestamp_sample"].astype(np.int64)[idx]
    assert age[1:].min() >= round(LATENCY_S * 1e6) and age[0] == 0
    # the rule is not met by the capture time: the newest sample captured by the tick differs
    errors = pd.read_parquet(res.out / "errors.parquet")
    captured = errors["stamp_ns"].to_numpy() // 1000
    newest = np.searchsorted(captured, tick_us, side="right") - 1
    assert (np.round(captured[newest]) != vio["timestamp_sample"][idx]).mean() > 0.9


def _fly(folder, px4=None, **over):
    opts = FlightOptions.model_validate(
        {"controller": {"kind": str(folder), **over.pop("controller", {})}, **over,
         **({"px4": px4} if px4 is not None else {})}
    )  # fmt: skip
    return fly(opts)


def test_no_latency_reads_as_before_the_standin(controller):
    """Read by arrival with no latency, jitter or drop (a latency that rounds to 0 ns), the
    flight is bit for bit the one read by capture time."""
    before = _fly(controller)
    after = _fly(controller, {"estimator_latency_s": 1e-12})
    assert after.vio_arrival_us is not None and before.vio_arrival_us is None
    for a, b in ((before.x, after.x), (before.ctrl_y, after.ctrl_y), (before.ctrl_u, after.ctrl_u)):
        assert np.array_equal(a, b)
    assert (
        SimOptions().model_dump(mode="json").keys()
        == SimOptions.model_validate({"px4": {"interface": "paper"}}).model_dump(mode="json").keys()
    )
    assert "px4" not in FlightOptions().model_dump()


def test_the_px4_interface_tracks_and_a_wrong_hover_estimate_offsets_the_height(controller):
    """With the hover estimate right the PX4 interface tracks the circle as well as the paper's
    (measured: RMS 0.0638 m vs 0.0651 m); 10 % off it is a thrust error
    ``w = m g (1 - T_true / T_est)`` whose steady height offset is the controller's own
    ``sum_t Phi_xx(t) B_thrust w`` (+5.71 cm, -6.98 cm), met to 1e-9 m on truth feedback."""
    paper = _fly(controller).metrics()["tracking_rms_m"]
    px4 = _fly(controller, {"interface": "px4"}).metrics()["tracking_rms_m"]
    assert px4 <= 1.02 * paper and px4 > 0.8 * paper, (px4, paper)

    from qsls.pipeline.control.artifacts import load_controller_dir

    cdir = load_controller_dir(controller)
    sum_xx = cdir.controller.taps.Phi_xx.sum(axis=0)
    b = cdir.controller.model.B[:, 2]
    hover = {"reference": {"kind": "hover"}, "controller": {"feedback": "truth"}}
    offsets = {}
    for est in (0.5, 0.55, 0.45):
        f = _fly(controller, {"interface": "px4", "hover_estimate": est}, **hover)
        last = f.t_ns >= f.t_ns[-1] - 5_000_000_000
        offsets[est] = float(np.mean(f.x[last, 2] - f.ref[last, 2]))
    assert abs(offsets[0.5]) < 1e-9
    for est, want_cm in ((0.55, 5.709), (0.45, -6.978)):
        w = MASS * GRAVITY * (1.0 - 0.5 / est)
        predicted = float((sum_xx @ b * w)[2])
        assert offsets[est] == pytest.approx(predicted, abs=1e-9)
        assert 100 * predicted == pytest.approx(want_cm, abs=1e-3)


def test_simulate_writes_a_standin_ulog_from_the_command_line(controller, tmp_path):
    cfg = tmp_path / "standin.yaml"
    cfg.write_text(
        yaml.safe_dump(
            {"duration": 6, "controller": {"backend": BACKEND},
             "px4": {"interface": "px4", "estimator_latency_s": LATENCY_S, "logger_dropouts": 3}}
        )
    )  # fmt: skip
    run = CliRunner().invoke(
        app,
        ["simulate", "--config", str(cfg), "--controller", str(controller), "--format", "ulog",
         "--out", str(tmp_path / "sim")],
    )  # fmt: skip
    assert run.exit_code == 0, run.output
    ulog = pyulog.ULog(str(tmp_path / "sim" / "flight.ulg"))
    truth = json.loads((tmp_path / "sim" / "truth.json").read_text())
    assert truth["format"] == "ulog"
    dropouts = truth["px4"]["logger_dropouts"]
    assert [d.duration for d in ulog.dropouts] == [ms for _, ms in dropouts] and len(dropouts) == 3
    for start, ms in dropouts:  # every topic lost what fell inside
        for ds in ulog.data_list:
            ts = ds.data["timestamp"].astype(np.int64)
            assert not np.any((ts >= start) & (ts < start + 1000 * ms)), ds.name
    assert (tmp_path / "sim" / "ticks.parquet").is_file()
    # a ULog records a PX4 vehicle: without the interface, a one-line error
    bad = CliRunner().invoke(
        app, ["simulate", "--controller", "pd", "--format", "ulog", "--out", str(tmp_path / "b")]
    )
    assert bad.exit_code != 0 and "px4.interface: px4" in bad.output
