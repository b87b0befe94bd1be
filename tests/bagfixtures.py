"""Known flights for the ingest tests: truth, and a VIO with injected offset, frame and noise.

The truth is an analytic 3-D flight (a Lissajous loop with climbing and banking), so its
position and velocity are known exactly at any time. The VIO sees it in its own world
frame ``p_vio = R0^T (p - t0)`` (so the alignment that recovers the truth frame is
``R0, t0``), on its own clock: truth stamps are ``t_true - offset`` where ``offset`` is the
``time_offset_s`` ingest must recover (added to truth stamps gives the VIO clock).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from qsls.pipeline.core.rotations import matrix_to_quat, quat_to_matrix, rot_z
from qsls.pipeline.ingest.sources.messages import OdometryStream, PoseStream
from qsls.pipeline.ingest.sources.msgtypes import TF
from qsls.pipeline.ingest.sources.write import write_bag

T0_NS = 1_700_000_000_000_000_000


def truth_state(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position, velocity and attitude quaternion (x y z w) at times ``t`` (s)."""
    w1, w2, w3 = 0.7, 1.1, 0.35
    p = np.column_stack(
        [1.5 * np.sin(w1 * t), 1.0 * np.sin(w2 * t + 0.4), 1.0 + 0.4 * np.sin(w3 * t)]
    )
    v = np.column_stack(
        [1.5 * w1 * np.cos(w1 * t), 1.0 * w2 * np.cos(w2 * t + 0.4), 0.4 * w3 * np.cos(w3 * t)]
    )
    yaw = 0.6 * np.sin(0.3 * t) + 0.2 * t
    roll = 0.15 * np.sin(0.9 * t)
    pitch = 0.1 * np.cos(0.8 * t)
    from scipy.spatial.transform import Rotation

    q = Rotation.from_euler("ZYX", np.column_stack([yaw, pitch, roll])).as_quat()
    return p, v, q


@dataclass(frozen=True)
class Flight:
    vio: OdometryStream
    truth: PoseStream
    offset_s: float
    yaw_rad: float
    rotation: np.ndarray
    translation: np.ndarray


def make_flight(
    *,
    duration: float = 30.0,
    vio_hz: float = 50.0,
    truth_hz: float = 100.0,
    offset_s: float = 0.083,
    yaw_deg: float = 37.0,
    rotation: np.ndarray | None = None,
    translation: tuple[float, float, float] = (2.0, -1.0, 0.3),
    noise_m: float = 0.002,
    noise_mps: float = 0.01,
    dropouts: tuple[tuple[float, float], ...] = ((12.0, 12.6),),
    seed: int = 0,
    truth_msgtype: str = "geometry_msgs/msg/PoseStamped",
    velocity_frame: str = "body",
    vio_topic: str = "/vio/odom",
    truth_topic: str = "/mocap/pose",
) -> Flight:
    rng = np.random.default_rng(seed)
    r0 = rot_z(np.radians(yaw_deg)) if rotation is None else np.asarray(rotation, float)
    t0 = np.asarray(translation, float)
    # VIO on its clock (= true time), with dropouts removed
    tv = np.arange(0.0, duration, 1.0 / vio_hz)
    for a, b in dropouts:
        tv = tv[(tv < a) | (tv > b)]
    p, v, q = truth_state(tv)
    p_vio = (p - t0) @ r0 + rng.normal(scale=noise_m, size=p.shape)  # R0^T (p - t0)
    rb = quat_to_matrix(q)
    q_vio = matrix_to_quat(r0.T[None] @ rb)
    v_world_vio = v @ r0  # R0^T v
    # body: R_b^T v (the same in every world frame); world: the VIO world frame's
    v_msg = np.einsum("nji,nj->ni", rb, v) if velocity_frame == "body" else v_world_vio
    v_msg = v_msg + rng.normal(scale=noise_mps, size=v.shape)
    vio_ns = T0_NS + np.round(tv * 1e9).astype(np.int64)
    vio = OdometryStream(
        vio_topic, vio_ns, vio_ns + 2_000_000, p_vio, q_vio, v_msg, np.zeros_like(v_msg)
    )
    # truth on a clock that reads t_true - offset
    tt = np.arange(-1.0, duration + 1.0, 1.0 / truth_hz)
    pt, _, qt = truth_state(tt)
    truth_ns = T0_NS + np.round((tt - offset_s) * 1e9).astype(np.int64)
    truth = PoseStream(truth_topic, truth_ns, truth_ns + 1_000_000, pt, qt, msgtype=truth_msgtype)
    return Flight(vio, truth, offset_s, float(np.arctan2(r0[1, 0], r0[0, 0])), r0, t0)


def write_flight(path: Path, fmt: str, flight: Flight | None = None, **kw) -> Path:
    flight = flight or make_flight(**kw)
    return write_bag(path, [flight.vio, flight.truth], fmt)


def bag_name(fmt: str, stem: str = "flight") -> str:
    return {"ros1": f"{stem}.bag", "mcap": f"{stem}.mcap"}.get(fmt, f"{stem}_{fmt}")


def tf_streams(truth: PoseStream, other_child: str, other_position: np.ndarray, log_shift_ns: int):
    """A ``/tf`` topic with two transforms: ``world -> quad`` (the truth) and ``quad -> other``."""
    main = PoseStream(
        "/tf",
        truth.header_ns,
        truth.log_ns,
        truth.position,
        truth.orientation,
        msgtype=TF,
        frame_id="world",
        child_frame_id="quad",
    )
    other = PoseStream(
        "/tf",
        truth.header_ns,
        truth.log_ns + log_shift_ns,
        other_position,
        truth.orientation,
        msgtype=TF,
        frame_id="quad",
        child_frame_id=other_child,
    )
    return main, other
