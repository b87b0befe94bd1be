"""``qsls simulate``: fly the vehicle and write its logs the way real ones arrive.

Output folder (stage ``simulate``, written through :class:`StageWriter`):

- the bag: ``flight.bag`` (ros1), ``flight/`` (rosbag2 folder: ros2-sqlite, ros2-mcap) or
  ``flight.mcap`` (plain MCAP); its name is in ``SimResult.bag`` and in the manifest's
  ``results.bag``. Topics: VIO ``nav_msgs/Odometry`` (twist in the body frame, ROS
  convention) and motion capture ``geometry_msgs/PoseStamped`` or ``TransformStamped``;
- ``truth.json``: ``time_offset_s``, ``vio_frame`` (``yaw_rad``, ``translation``),
  ``lipschitz`` (null for the camera loop: no designed bias field), the emulator's
  parameters, ``crashed`` and the flight's metrics;
- ``errors.parquet``: the emulator's error at every VIO sample, in the motion-capture
  (world) frame before the VIO frame's transform: ``stamp_ns`` (VIO clock), ``e_px`` ..
  ``e_vz``, and the true state ``x_px`` .. ``x_vz`` there;
- ``trajectory.parquet`` (truth and reference at the physics rate, VIO clock),
  ``control.parquet`` (what the controller saw and commanded at each tick, VIO clock) and
  ``ticks.parquet``: the controller's own log (:mod:`qsls.pipeline.sim.ticks`: the true state,
  the reading, the input, the reference and its feedforward at each tick, flight time), from
  which ``qsls evaluate --flown-by`` checks every assumption of the controller's guarantee;
- ``camera_frame.npz`` (camera loop only): one frame and the features tracked on it.

With ``log.format: ulog`` (and ``px4.interface: px4``) the log is ``flight.ulg`` instead of
a bag: the flight as PX4 would log it (:mod:`qsls.pipeline.sim.px4log`, PX4's boot clock in
µs, NED), and ``truth.json`` and the manifest's results gain ``px4`` (hover thrust and its
estimate, the estimate's and the motion capture's latency, jitter, drops and message counts,
the logger dropouts, the controller's sha256 and gate). With ``log.format: mavros`` (and
``px4.interface: px4``) it is ``flight.bag``, the same record as a mavros user's ROS1 bag
(:mod:`qsls.pipeline.sim.mavroslog`, the ROS clock, ENU), with the same ``px4`` block.

Clocks (docs/conventions.md#clocks): ``time_offset_s`` is added to motion-capture stamps to put
them on the VIO clock, so ``mocap_stamp = vio_clock(t) - time_offset_s``. The bag's log time
is the recorder's clock, here the VIO computer's: ``log = (stamp on the VIO clock) +
transport delay + jitter``.

Frames: the VIO world frame is yawed by ``vio_frame_yaw_deg`` and shifted by
``vio_frame_translation`` in the motion-capture frame: ``p_mocap = R_z(yaw) p_vio + t``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.control.artifacts import CERTIFICATE_FILE, Certificate
from qsls.pipeline.core.artifacts import StageWriter, npz_bytes
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.core.rotations import quat_mul
from qsls.pipeline.ingest.sources.messages import OdometryStream, PoseStream
from qsls.pipeline.ingest.sources.ulog.writer import write_ulog
from qsls.pipeline.ingest.sources.write import write_bag
from qsls.pipeline.sim.closedloop import NS, FlightLog, fly
from qsls.pipeline.sim.controllers import PositionController, controller_folder
from qsls.pipeline.sim.mavroslog import BAG_FORMAT as MAVROS_BAG_FORMAT
from qsls.pipeline.sim.mavroslog import mavros_log
from qsls.pipeline.sim.mocap import sample_mocap
from qsls.pipeline.sim.options import LogOptions as LogOptions
from qsls.pipeline.sim.options import SimOptions
from qsls.pipeline.sim.px4log import ULOG_NAME, Identity, px4_log
from qsls.pipeline.sim.ticks import TICKS_FILE, TickLog, tick_log

STAGE = "simulate"
FORMATS = ("ros1", "ros2-sqlite", "ros2-mcap", "mcap")
STATE = ("px", "py", "pz", "vx", "vy", "vz")
# SeedSequence stream for the logger (mocap noise, delay jitter); the VIO uses its own.
_LOG_STREAM = 1000

CONTROL_FILE = "control.parquet"
"""What the controller saw and commanded at each tick (``stamp_ns``, ``y_*``, ``r_*``, ``u_*``)."""
TRUTH_FILE = "truth.json"
"""What the simulator knows that the log does not (clock offset, VIO frame, perception, crash)."""
CAMERA_FRAME = "camera_frame.npz"
"""The camera loop's kept frame (``vio.camera.snapshot_s``) and its tracked features."""


@dataclass(frozen=True)
class SimResult:
    out: Path
    bag: Path
    flight: FlightLog
    metrics: dict[str, Any]
    truth: dict[str, Any]
    ticks: TickLog
    """The controller's own log of the flight (``ticks.parquet``)."""

    def summary(self) -> dict[str, Any]:
        m = self.metrics
        out = {
            "output": str(self.out),
            "bag": str(self.bag),
            "format": self.truth["format"],
            "controller": self.flight.controller,
            "duration (s)": round(m["duration_s"], 3),
            "tracking RMS (m)": m["tracking_rms_m"],
            "tracking max (m)": m["tracking_max_m"],
            "perception error RMS (inf-norm)": m["perception_error_rms"],
            "perception error max (inf-norm)": m["perception_error_max"],
            "bias Lipschitz L": (
                "none (camera loop)" if self.truth["lipschitz"] is None else self.truth["lipschitz"]
            ),
            "crashed": self.flight.crashed,
        }
        if self.flight.crashed:
            out["crash"] = self.flight.crash_reason
        return out


def bag_name(fmt: str) -> str:
    """The bag's name inside the output folder for a format."""
    names = {"ros1": "flight.bag", "mavros": "flight.bag", "mcap": "flight.mcap", "ulog": ULOG_NAME}
    return names.get(fmt, "flight")


def _rz(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _quat_z(yaw: float, n: int) -> np.ndarray:
    return np.tile([0.0, 0.0, np.sin(0.5 * yaw), np.cos(0.5 * yaw)], (n, 1))


def _rotate_by_conj(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``R(q)^T v`` row by row (world vector into the body frame)."""
    x, y, z, w = q.T
    r = np.empty((len(q), 3, 3))
    r[:, 0, 0] = 1 - 2 * (y * y + z * z)
    r[:, 0, 1] = 2 * (x * y - z * w)
    r[:, 0, 2] = 2 * (x * z + y * w)
    r[:, 1, 0] = 2 * (x * y + z * w)
    r[:, 1, 1] = 1 - 2 * (x * x + z * z)
    r[:, 1, 2] = 2 * (y * z - x * w)
    r[:, 2, 0] = 2 * (x * z - y * w)
    r[:, 2, 1] = 2 * (y * z + x * w)
    r[:, 2, 2] = 1 - 2 * (x * x + y * y)
    return np.einsum("nji,nj->ni", r, v)


def log_streams(
    flight: FlightLog, options: SimOptions, seed: int
) -> tuple[list[Any], dict[str, Any]]:
    """The bag's streams (VIO odometry, motion capture) and the clock/frame truth."""
    lo = options.log
    rng = np.random.default_rng(np.random.SeedSequence([seed, _LOG_STREAM]))
    start_ns = round(lo.vio_clock_start_s * NS)
    offset_ns = round(lo.time_offset_s * NS)
    yaw = np.radians(lo.vio_frame_yaw_deg)
    trans = np.asarray(lo.vio_frame_translation, dtype=float)
    rz = _rz(yaw)

    # VIO: y = x + e in the mocap frame, then expressed in the VIO frame
    y = flight.vio_y
    n = len(y)
    p_vio = (y[:, :3] - trans) @ rz  # rows: R_z^T (p - t)
    # the attitude the estimator reports: the true one (emulator) or the filter's (camera)
    q_est = flight.vio_q if flight.vio_q_est is None else flight.vio_q_est
    q_vio = quat_mul(_quat_z(-yaw, n), q_est)
    twist = _rotate_by_conj(q_est, y[:, 3:])  # R_body^T v_world (= in VIO frame too)
    vio_stamp = start_ns + flight.vio_t_ns
    jit = rng.uniform(0.0, lo.delay_jitter_s, n)
    vio_log = np.maximum.accumulate(
        vio_stamp + np.round((lo.vio_delay_s + jit) * NS).astype(np.int64)
    )
    vio = OdometryStream(
        topic=lo.vio_topic,
        header_ns=vio_stamp.astype(np.int64),
        log_ns=vio_log.astype(np.int64),
        position=p_vio,
        orientation=q_vio,
        linear_velocity=twist,
        angular_velocity=flight.vio_w,
        frame_id=lo.vio_frame_id,
        child_frame_id=lo.vio_child_frame_id,
    )

    # motion capture: its own clock, the world frame
    mc = sample_mocap(options.mocap, flight.t_ns, flight.x, flight.q, rng)
    on_vio_clock = start_ns + mc.t_ns
    mocap_stamp = on_vio_clock - offset_ns
    jit = rng.uniform(0.0, lo.delay_jitter_s, len(mc.t_ns))
    mocap_log = np.maximum.accumulate(
        on_vio_clock + np.round((lo.mocap_delay_s + jit) * NS).astype(np.int64)
    )
    mocap = PoseStream(
        topic=lo.mocap_topic,
        header_ns=mocap_stamp.astype(np.int64),
        log_ns=mocap_log.astype(np.int64),
        position=mc.position,
        orientation=mc.orientation,
        msgtype=f"geometry_msgs/msg/{lo.mocap_msgtype}",
        frame_id=lo.mocap_frame_id,
        child_frame_id=lo.mocap_child_frame_id,
    )
    truth = {
        "time_offset_s": lo.time_offset_s,
        "vio_frame": {"yaw_rad": float(yaw), "translation": [float(v) for v in trans]},
        "vio_clock_start_ns": int(start_ns),
        "vio_topic": lo.vio_topic,
        "mocap_topic": lo.mocap_topic,
        "mocap_msgtype": mocap.msgtype,
        "vio_rate_hz": options.vio.rate_hz,
        "mocap_rate_hz": options.mocap.rate_hz,
        "vio_messages": n,
        "mocap_messages": len(mc.t_ns),
    }
    return [vio, mocap], truth


def _frames(flight: FlightLog, start_ns: int) -> dict[str, Any]:
    import pandas as pd

    def cols(prefix: str, a: np.ndarray) -> dict[str, np.ndarray]:
        return {f"{prefix}_{s}": a[:, i] for i, s in enumerate(STATE)}

    errors = pd.DataFrame(
        {
            "stamp_ns": start_ns + flight.vio_t_ns,
            **cols("e", flight.vio_e),
            **cols("x", flight.vio_x),
        }
    )
    traj = pd.DataFrame(
        {
            "stamp_ns": start_ns + flight.t_ns,
            "t": flight.t_ns / NS,
            **cols("x", flight.x),
            **cols("r", flight.ref),
            **{f"q_{c}": flight.q[:, i] for i, c in enumerate("xyzw")},
        }
    )
    control = pd.DataFrame(
        {
            "stamp_ns": start_ns + flight.ctrl_t_ns,
            "t": flight.ctrl_t_ns / NS,
            **cols("y", flight.ctrl_y),
            **cols("r", flight.ctrl_ref),
            "u_pitch": flight.ctrl_u[:, 0],
            "u_roll": flight.ctrl_u[:, 1],
            "u_thrust": flight.ctrl_u[:, 2],
        }
    )
    return {"errors.parquet": errors, "trajectory.parquet": traj, CONTROL_FILE: control}


def controller_identity(
    options: SimOptions, flight: FlightLog, controller: PositionController | None
) -> Identity:
    """The flown controller's name, and its certificate's sha256 and gate where it has one."""
    kind = options.controller.kind
    if controller is not None or kind in ("se3", "pd"):
        return Identity(flight.controller)
    folder = controller_folder(kind)
    if not (folder / CERTIFICATE_FILE).is_file():
        return Identity(flight.controller)
    cert = Certificate.load(folder)
    return Identity(flight.controller, cert.controller_sha256, cert.gate)


def ulog_streams(
    flight: FlightLog, options: SimOptions, seed: int, path: Path, controller: Any = None
) -> dict[str, Any]:
    """Write the flight's ULog to ``path``; the clock truth (as :func:`log_streams`'s, on
    PX4's boot clock, in the simulator's world: no VIO frame) with the log's ``px4`` block."""
    content, px4 = px4_log(flight, options, seed, controller_identity(options, flight, controller))
    write_ulog(path, content)
    boot_ns = px4["boot_us"] * 1000
    return {
        "time_offset_s": 0.0,
        "vio_frame": {"yaw_rad": 0.0, "translation": [0.0, 0.0, 0.0]},
        "vio_clock_start_ns": int(boot_ns),
        "vio_topic": px4["estimator"]["topic"],
        "mocap_topic": px4["mocap"]["topic"],
        "vio_rate_hz": options.vio.rate_hz,
        "mocap_rate_hz": options.mocap.rate_hz,
        "vio_messages": px4["estimator"]["samples"] - px4["estimator"]["dropped"],
        "mocap_messages": px4["mocap"]["samples"] - px4["mocap"]["dropped"],
        "px4": px4,
    }


def simulate(
    options: SimOptions,
    out: Path,
    *,
    force: bool = False,
    progress: Progress = NULL_PROGRESS,
    controller: PositionController | None = None,
    inputs: list[Path] | None = None,
) -> SimResult:
    """Fly ``options`` (or the given ``controller``) and write the stage folder ``out``."""
    out = Path(out)
    ctrl_inputs = list(inputs or [])
    if controller is None and options.controller.kind not in ("se3", "pd"):
        ctrl_inputs.append(controller_folder(options.controller.kind))
    with StageWriter(out, STAGE, options=options, inputs=ctrl_inputs, force=force) as w:
        flight = fly(options, controller, progress=progress)
        progress.start("writing the bag", total=None)
        name = bag_name(options.log.format)
        if options.log.format == "ulog":
            clocks = ulog_streams(flight, options, options.seed, w.path(name), controller)
        elif options.log.format == "mavros":
            identity = controller_identity(options, flight, controller)
            streams, clocks = mavros_log(flight, options, options.seed, identity)
            write_bag(w.path(name), streams, MAVROS_BAG_FORMAT, compression=options.log.compression)
        else:
            streams, clocks = log_streams(flight, options, options.seed)
            write_bag(
                w.path(name), streams, options.log.format, compression=options.log.compression
            )
        progress.finish()
        metrics = flight.metrics()
        truth = {
            **clocks,
            "format": options.log.format,
            "bag": name,
            "seed": options.seed,
            "controller": flight.controller,
            "controller_dt": flight.dt,
            "feedback": options.controller.feedback,
            "lipschitz": flight.lipschitz,
            "emulator": {"params": options.vio.model_dump(mode="json"), **flight.emulator},
            "crashed": flight.crashed,
            "crash_reason": flight.crash_reason,
            "crash_time_s": flight.crash_time_s,
            "metrics": metrics,
            "mass": flight.mass,
        }
        w.write_json(TRUTH_FILE, truth)
        if flight.camera_frame is not None:
            w.write_bytes(CAMERA_FRAME, npz_bytes(flight.camera_frame))
        for fname, df in _frames(flight, clocks["vio_clock_start_ns"]).items():
            w.write_parquet(fname, df)
        identity = controller_identity(options, flight, controller)
        ticks = tick_log(flight, identity.sha256 or "")
        w.write_parquet(TICKS_FILE, ticks.frame())
        w.results.update(
            {
                "bag": name,
                "format": options.log.format,
                "crashed": flight.crashed,
                "crash_reason": flight.crash_reason,
                "lipschitz": flight.lipschitz,
                "time_offset_s": clocks["time_offset_s"],
                **({"px4": clocks["px4"]} if "px4" in clocks else {}),
                **{k: v for k, v in metrics.items() if k not in ("crashed", "crash_reason")},
            }
        )
    return SimResult(
        out=out, bag=out / name, flight=flight, metrics=metrics, truth=truth, ticks=ticks
    )
