"""The PX4 stand-in's log: a flight as PX4 itself would write it (``flight.ulg``).

docs/simulation.md#the-px4-stand-in. :func:`px4_log` turns a flown :class:`FlightLog` into
the topics of a PX4 >= 1.14 ULog, with PX4's own field names and types (float32 where PX4
has them), written by :func:`qsls.pipeline.ingest.sources.ulog.writer.write_ulog`:

- the clock: µs since boot, the flight's ``t = 0`` at ``px4.boot_s``;
- frames: NED world, FRD body, quaternions ``[w, x, y, z]``
  (:mod:`qsls.pipeline.sim.px4`);
- ``vehicle_visual_odometry``: every VIO estimate that arrived, at its arrival time
  (``timestamp``; captured at ``timestamp_sample``), the one the controller read by the rule
  of :mod:`qsls.pipeline.sim.closedloop`;
- ``vehicle_mocap_odometry``: the motion capture (noisy pose, true velocity and body rate)
  with its own latency, jitter and drops;
- ``vehicle_attitude_setpoint`` and ``trajectory_setpoint``: one per controller tick, at the
  tick's time exactly: the attitude and normalized thrust the interface sent, the reference
  the controller used;
- ``hover_thrust_estimate`` (10 Hz, the interface's hover estimate) and
  ``vehicle_local_position`` (the truth at 50 Hz, the vehicle's own estimate in a real log);
- parameters ``MPC_THR_HOVER``, ``THR_MDL_FAC``, ``SDLOG_PROFILE``; info ``sys_name``,
  ``ver_sw`` and the controller's identity (``qsls_controller``, ``qsls_controller_sha256``,
  ``qsls_gate``);
- logger dropouts (``px4.logger_dropouts``): every topic loses its messages inside each.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from qsls.pipeline.core.plant import feedforward_acceleration
from qsls.pipeline.core.units import NS
from qsls.pipeline.ingest.sources.ulog.writer import LogContent, Topic
from qsls.pipeline.sim.closedloop import FlightLog
from qsls.pipeline.sim.mocap import interpolate_truth, sample_mocap
from qsls.pipeline.sim.options import Px4Options, SimOptions, VioParams
from qsls.pipeline.sim.px4 import (
    US,
    arrivals,
    enu_to_ned,
    euler_zyx,
    flu_to_frd,
    quat_enu_flu_to_ned_frd,
)

ULOG_NAME = "flight.ulg"
SDLOG_PROFILE = 129
"""The logger profile recorded (bit 7 set, as the stand-in's logs are tagged)."""
HOVER_ESTIMATE_HZ = 10.0
LOCAL_POSITION_HZ = 50.0
# SeedSequence streams of the log's own randomness (the VIO, the estimate's transport and the
# bag logger use others)
_LOG_STREAM = 1000  # the bag logger's (qsls.pipeline.sim.simulate): the same mocap noise
_MOCAP_TRANSPORT_STREAM = 2001
_DROPOUT_STREAM = 2002

ODOMETRY_FIELDS = (
    ("uint64_t", "timestamp"), ("uint64_t", "timestamp_sample"), ("float[3]", "position"),
    ("float[4]", "q"), ("float[3]", "velocity"), ("float[3]", "angular_velocity"),
    ("float[3]", "position_variance"), ("float[3]", "orientation_variance"),
    ("float[3]", "velocity_variance"), ("uint8_t", "pose_frame"), ("uint8_t", "velocity_frame"),
    ("uint8_t", "reset_counter"), ("int8_t", "quality"),
)  # fmt: skip
"""``vehicle_odometry`` (PX4 >= 1.14): ``vehicle_visual_odometry``, ``vehicle_mocap_odometry``."""
POSE_FRAME_NED = 1
VELOCITY_FRAME_NED = 1
ATTITUDE_SETPOINT_FIELDS = (
    ("uint64_t", "timestamp"), ("float", "roll_body"), ("float", "pitch_body"),
    ("float", "yaw_body"), ("float", "yaw_sp_move_rate"), ("float[4]", "q_d"),
    ("float[3]", "thrust_body"), ("bool", "reset_integral"), ("bool", "fw_control_yaw_wheel"),
)  # fmt: skip
TRAJECTORY_SETPOINT_FIELDS = (
    ("uint64_t", "timestamp"), ("float[3]", "position"), ("float[3]", "velocity"),
    ("float[3]", "acceleration"), ("float[3]", "jerk"), ("float", "yaw"), ("float", "yawspeed"),
)  # fmt: skip
HOVER_THRUST_FIELDS = (
    ("uint64_t", "timestamp"), ("uint64_t", "timestamp_sample"), ("float", "hover_thrust"),
    ("float", "hover_thrust_var"), ("float", "accel_innov"), ("float", "accel_innov_var"),
    ("float", "accel_innov_test_ratio"), ("float", "accel_noise_var"), ("bool", "valid"),
)  # fmt: skip
LOCAL_POSITION_FIELDS = (
    ("uint64_t", "timestamp"), ("uint64_t", "timestamp_sample"), ("bool", "xy_valid"),
    ("bool", "z_valid"), ("bool", "v_xy_valid"), ("bool", "v_z_valid"), ("float", "x"),
    ("float", "y"), ("float", "z"), ("float[2]", "delta_xy"), ("uint8_t", "xy_reset_counter"),
    ("float", "delta_z"), ("uint8_t", "z_reset_counter"), ("float", "vx"), ("float", "vy"),
    ("float", "vz"), ("float", "z_deriv"), ("float[2]", "delta_vxy"),
    ("uint8_t", "vxy_reset_counter"), ("float", "delta_vz"), ("uint8_t", "vz_reset_counter"),
    ("float", "ax"), ("float", "ay"), ("float", "az"), ("float", "heading"),
    ("float", "unaided_heading"), ("float", "delta_heading"),
    ("uint8_t", "heading_reset_counter"), ("bool", "heading_good_for_control"),
    ("bool", "xy_global"), ("bool", "z_global"), ("uint64_t", "ref_timestamp"),
    ("double", "ref_lat"), ("double", "ref_lon"), ("float", "ref_alt"),
    ("float", "dist_bottom"), ("bool", "dist_bottom_valid"),
    ("uint8_t", "dist_bottom_sensor_bitfield"), ("float", "eph"), ("float", "epv"),
    ("float", "evh"), ("float", "evv"), ("bool", "dead_reckoning"), ("float", "vxy_max"),
    ("float", "vz_max"), ("float", "hagl_min"), ("float", "hagl_max"),
)  # fmt: skip
"""``vehicle_local_position`` (PX4 >= 1.14; fields the stand-in does not model are 0)."""


@dataclass(frozen=True)
class Identity:
    """The controller a log records: its name, its certificate's ``controller_sha256`` and
    gate (``None`` where it has none)."""

    name: str
    sha256: str | None = None
    gate: float | None = None

    def info(self) -> dict[str, str]:
        return {
            "qsls_controller": self.name,
            "qsls_controller_sha256": self.sha256 or "none",
            "qsls_gate": "none" if self.gate is None else repr(float(self.gate)),
        }


def _odometry(
    name: str, ts: np.ndarray, ts_sample: np.ndarray, p_enu: np.ndarray, q_xyzw: np.ndarray,
    v_enu: np.ndarray, w_flu: np.ndarray, variances: tuple[float, float, float],
) -> Topic:  # fmt: skip
    n = len(ts)
    return Topic(
        name,
        ODOMETRY_FIELDS,
        {
            "timestamp": ts,
            "timestamp_sample": ts_sample,
            "position": enu_to_ned(p_enu),
            "q": quat_enu_flu_to_ned_frd(q_xyzw) if n else np.zeros((0, 4)),
            "velocity": enu_to_ned(v_enu),
            "angular_velocity": flu_to_frd(w_flu),
            "position_variance": np.full((n, 3), variances[0]),
            "orientation_variance": np.full((n, 3), variances[1]),
            "velocity_variance": np.full((n, 3), variances[2]),
            "pose_frame": np.full(n, POSE_FRAME_NED),
            "velocity_frame": np.full(n, VELOCITY_FRAME_NED),
            "reset_counter": np.zeros(n),
            "quality": np.full(n, 100),
        },
    )


def _every(period_ns: int, end_ns: int) -> np.ndarray:
    return np.arange(0, end_ns + 1, period_ns, dtype=np.int64)


def _local_position(flight: FlightLog, boot_us: int) -> Topic:
    """The truth at :data:`LOCAL_POSITION_HZ` (what EKF2 would estimate, without its error)."""
    t_ns = _every(round(NS / LOCAL_POSITION_HZ), int(flight.t_ns[-1]))
    p, v, q = interpolate_truth(flight.t_ns, flight.x, flight.q, t_ns)
    t = flight.t_ns / NS
    acc = np.gradient(flight.x[:, 3:], t, axis=0) if len(t) > 1 else np.zeros((1, 3))
    a = np.column_stack([np.interp(t_ns / NS, t, acc[:, j]) for j in range(3)])
    pn, vn, an = enu_to_ned(p), enu_to_ned(v), enu_to_ned(a)
    heading = euler_zyx(quat_enu_flu_to_ned_frd(q))[:, 2]
    n = len(t_ns)
    ts = boot_us + t_ns // US
    one, zero = np.ones(n), np.zeros(n)
    data = {
        "timestamp": ts, "timestamp_sample": ts, "xy_valid": one, "z_valid": one,
        "v_xy_valid": one, "v_z_valid": one, "x": pn[:, 0], "y": pn[:, 1], "z": pn[:, 2],
        "vx": vn[:, 0], "vy": vn[:, 1], "vz": vn[:, 2], "z_deriv": vn[:, 2],
        "ax": an[:, 0], "ay": an[:, 1], "az": an[:, 2], "heading": heading,
        "unaided_heading": heading, "heading_good_for_control": one, "dist_bottom": p[:, 2],
        "dist_bottom_valid": one, "dist_bottom_sensor_bitfield": one, "eph": zero, "epv": zero,
        "evh": zero, "evv": zero,
    }  # fmt: skip
    return Topic("vehicle_local_position", LOCAL_POSITION_FIELDS, data)


def _feedforward_acc(flight: FlightLog) -> np.ndarray:
    """The reference acceleration at each tick that the controller's feedforward stands for,
    ``B^-1 uff`` with the controller's mass."""
    assert flight.ctrl_uff is not None, "every flight records the feedforward it flew"
    return feedforward_acceleration(flight.ctrl_uff, flight.controller_mass or flight.mass)


def _setpoints(flight: FlightLog, boot_us: int) -> list[Topic]:
    """``vehicle_attitude_setpoint`` and ``trajectory_setpoint`` at every tick."""
    if flight.ctrl_sp is None or flight.ctrl_acc is None:
        raise ValueError("a PX4 log needs a flight flown with px4.interface: px4")
    k = len(flight.ctrl_t_ns)
    ts = boot_us + flight.ctrl_t_ns // US
    q_d = quat_enu_flu_to_ned_frd(flight.ctrl_sp[:, 1:]) if k else np.zeros((0, 4))
    eul = euler_zyx(q_d) if k else np.zeros((0, 3))
    thrust = np.zeros((k, 3))
    thrust[:, 2] = -flight.ctrl_sp[:, 0]
    att = Topic(
        "vehicle_attitude_setpoint",
        ATTITUDE_SETPOINT_FIELDS,
        {
            "timestamp": ts, "roll_body": eul[:, 0], "pitch_body": eul[:, 1],
            "yaw_body": eul[:, 2], "yaw_sp_move_rate": np.zeros(k), "q_d": q_d,
            "thrust_body": thrust, "reset_integral": np.zeros(k), "fw_control_yaw_wheel": np.zeros(k),
        },
    )  # fmt: skip
    traj = Topic(
        "trajectory_setpoint",
        TRAJECTORY_SETPOINT_FIELDS,
        {
            "timestamp": ts,
            "position": enu_to_ned(flight.ctrl_ref[:, :3]),
            "velocity": enu_to_ned(flight.ctrl_ref[:, 3:]),
            # the acceleration the controller's feedforward stood for (its model's, issue 47):
            # what an ingest turns back into uff with the vehicle's mass
            "acceleration": enu_to_ned(_feedforward_acc(flight)),
            "jerk": np.full((k, 3), np.nan),  # not used by the controller (PX4: NaN = unset)
            "yaw": np.full(k, 0.5 * np.pi),  # ENU yaw 0: the body x axis points east
            "yawspeed": np.zeros(k),
        },
    )
    return [att, traj]


def _dropouts(
    topics: list[Topic], count: int, end_us: int, boot_us: int, rng: np.random.Generator
) -> tuple[list[Topic], list[tuple[int, int]]]:
    """``count`` logger dropouts of 5 to 50 ms at random times: each topic's messages with a
    ``timestamp`` inside one are lost."""
    if count == 0:
        return topics, []
    start = np.sort(rng.integers(0, max(end_us, 1), count)) + boot_us
    ms = rng.integers(5, 51, count)
    out = []
    for t in topics:
        ts = np.asarray(t.data["timestamp"], dtype=np.int64)
        lost = np.zeros(len(ts), dtype=bool)
        for s, d in zip(start.tolist(), ms.tolist(), strict=True):
            lost |= (ts >= s) & (ts < s + d * 1000)
        keep = ~lost
        out.append(Topic(t.name, t.fields, {k: np.asarray(v)[keep] for k, v in t.data.items()}))
    return out, [(int(s), int(d)) for s, d in zip(start, ms, strict=True)]


def _visual_odometry(
    flight: FlightLog, arrival_us: np.ndarray, dropped: np.ndarray, vio: VioParams, boot_us: int
) -> tuple[Topic, np.ndarray]:
    """The estimator's topic: the samples that arrived, at their arrival (and which did)."""
    got = ~dropped
    y = flight.vio_y[got]
    q_est = flight.vio_q if flight.vio_q_est is None else flight.vio_q_est
    var = (
        (vio.noise_position**2, np.nan, vio.noise_velocity**2)
        if vio.kind == "emulator"
        else (np.nan, np.nan, np.nan)
    )
    visual = _odometry(
        "vehicle_visual_odometry", boot_us + arrival_us[got],
        boot_us + np.round(flight.vio_t_ns[got] / US).astype(np.int64), y[:, :3], q_est[got],
        y[:, 3:], flight.vio_w[got], var,
    )  # fmt: skip
    return visual, got


def _mocap_odometry(
    flight: FlightLog, options: SimOptions, seed: int, boot_us: int
) -> tuple[Topic, int, np.ndarray]:
    """The motion capture's topic: noisy pose, true velocity and body rate, its own transport
    (and how many samples it took, which arrived)."""
    px4 = options.px4
    log_rng = np.random.default_rng(np.random.SeedSequence([seed, _LOG_STREAM]))
    mc = sample_mocap(options.mocap, flight.t_ns, flight.x, flight.q, log_rng)
    _, v_mc, _ = interpolate_truth(flight.t_ns, flight.x, flight.q, mc.t_ns)
    w_mc = np.column_stack(
        [np.interp(mc.t_ns, flight.t_ns, flight.w[:, j]) for j in range(3)]
    ).reshape(-1, 3)
    mc_rng = np.random.default_rng(np.random.SeedSequence([seed, _MOCAP_TRANSPORT_STREAM]))
    mc_arr, mc_drop = arrivals(
        mc.t_ns, px4.mocap_latency_s, px4.mocap_jitter_s, px4.mocap_drop, mc_rng
    )
    keep = ~mc_drop
    mocap = _odometry(
        "vehicle_mocap_odometry", boot_us + mc_arr[keep],
        boot_us + np.round(mc.t_ns[keep] / US).astype(np.int64), mc.position[keep],
        mc.orientation[keep], v_mc[keep], w_mc[keep],
        (options.mocap.position_noise**2, options.mocap.attitude_noise**2, np.nan),
    )  # fmt: skip
    return mocap, len(mc.t_ns), keep


def _hover_estimate(px4: Px4Options, end_ns: int, boot_us: int) -> Topic:
    """PX4's hover-thrust estimate, constant at ``px4.estimate``, at :data:`HOVER_ESTIMATE_HZ`."""
    hts = boot_us + _every(round(NS / HOVER_ESTIMATE_HZ), end_ns) // US
    nh = len(hts)
    return Topic(
        "hover_thrust_estimate",
        HOVER_THRUST_FIELDS,
        {
            "timestamp": hts, "timestamp_sample": hts,
            "hover_thrust": np.full(nh, px4.estimate), "hover_thrust_var": np.full(nh, 1e-6),
            "accel_innov": np.zeros(nh), "accel_innov_var": np.full(nh, 0.1),
            "accel_innov_test_ratio": np.zeros(nh), "accel_noise_var": np.full(nh, 0.1),
            "valid": np.ones(nh),
        },
    )  # fmt: skip


def px4_log(
    flight: FlightLog, options: SimOptions, seed: int, identity: Identity
) -> tuple[LogContent, dict[str, Any]]:
    """The flight's ULog content and its truth (module docstring)."""
    px4 = options.px4
    if flight.vio_arrival_us is None or flight.vio_dropped is None:
        raise ValueError("a PX4 log needs a flight whose estimates were read by arrival")
    boot_us = round(px4.boot_s * 1e6)
    vio = options.vio
    visual, got = _visual_odometry(flight, flight.vio_arrival_us, flight.vio_dropped, vio, boot_us)
    mocap, n_mc, keep = _mocap_odometry(flight, options, seed, boot_us)
    end_ns = int(flight.t_ns[-1])
    hover = _hover_estimate(px4, end_ns, boot_us)
    topics = [visual, mocap, *_setpoints(flight, boot_us), hover, _local_position(flight, boot_us)]
    drop_rng = np.random.default_rng(np.random.SeedSequence([seed, _DROPOUT_STREAM]))
    topics, dropouts = _dropouts(topics, px4.logger_dropouts, end_ns // US, boot_us, drop_rng)
    content = LogContent(
        topics=topics,
        parameters={
            "MPC_THR_HOVER": float(px4.hover_thrust),
            "THR_MDL_FAC": float(px4.thr_mdl_fac),
            "SDLOG_PROFILE": SDLOG_PROFILE,
        },
        info={"sys_name": "qsls stand-in", "ver_sw": "qsls", **identity.info()},
        dropouts=dropouts,
        start_us=boot_us,
    )
    n_vio = len(flight.vio_t_ns)
    truth = {
        "boot_us": boot_us,
        "interface": px4.interface,
        "hover_thrust": px4.hover_thrust,
        "hover_estimate": px4.estimate,
        "thr_mdl_fac": px4.thr_mdl_fac,
        "controller_mass": flight.controller_mass or flight.mass,
        "controller": identity.name,
        "controller_sha256": identity.sha256,
        "gate": identity.gate,
        "estimator": {
            "topic": visual.name, "rate_hz": vio.rate_hz, "latency_s": px4.estimator_latency_s,
            "jitter_s": px4.estimator_jitter_s, "drop": px4.estimator_drop, "samples": n_vio,
            "dropped": int(n_vio - got.sum()),
        },
        "mocap": {
            "topic": mocap.name, "rate_hz": options.mocap.rate_hz,
            "latency_s": px4.mocap_latency_s, "jitter_s": px4.mocap_jitter_s,
            "drop": px4.mocap_drop, "samples": n_mc, "dropped": int(n_mc - keep.sum()),
        },
        "setpoints": len(flight.ctrl_t_ns),
        "logger_dropouts": [list(d) for d in dropouts],
    }  # fmt: skip
    return content, truth
