"""The PX4 stand-in as a mavros vehicle: the flight as a ROS user with mavros records it
(``log.format: mavros``: ``flight.bag``, ROS1). docs/simulation.md#the-px4-stand-in.

The record is the stand-in's ULog (:func:`qsls.pipeline.sim.px4log.px4_log`: the same
estimates that arrived, the same motion-capture samples with their noise, latency and drops,
the same setpoints, the same logger dropouts), its topics taken as they are and turned into
ROS conventions (ENU world, FLU body, quaternions ``[x, y, z, w]``, float64) on the ROS clock
(``log.vio_clock_start_s`` at the flight's ``t = 0``, nanoseconds):

- ``log.vio_topic`` (``nav_msgs/Odometry``): every estimate that arrived, bag log time = its
  arrival (the controller read the newest arrived one at each tick), header stamp = its
  capture; the pose in the world frame (ENU, the frame the controller flew in), the twist in
  the body frame (ROS convention);
- ``log.mocap_topic`` (``log.mocap_msgtype``, a vrpn / vicon bridge's): the motion capture,
  header stamp = its capture, log time = its arrival;
- ``/mavros/setpoint_raw/attitude`` (``mavros_msgs/AttitudeTarget``, :data:`COMMANDS`): the
  controller's own command, one per tick, header stamp = the tick: ``q_d`` (FLU in ENU) and
  the normalized thrust ``T`` the PX4 interface sent (``hover_estimate * thrust / (m g)``;
  mavros' ``thrust_scaling`` 1), rates ignored;
- ``/qsls/reference`` (``mavros_msgs/PositionTarget``, :data:`REFERENCE`): one per tick,
  stamped at the tick: the reference the controller tracked (position, velocity,
  acceleration; ``FRAME_LOCAL_NED``, mavros' name for the ENU local frame; yaw 0: east).

What a bag has no place for: the hover thrust (``qsls ingest --hover-thrust``), the
controller's identity (the replay proves who flew).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from qsls.pipeline.core.rotations import world_to_body
from qsls.pipeline.core.units import NS
from qsls.pipeline.ingest.sources.messages import (
    AttitudeTargetStream,
    OdometryStream,
    PoseStream,
    PositionTargetStream,
    Stream,
)
from qsls.pipeline.sim.closedloop import FlightLog
from qsls.pipeline.sim.options import SimOptions
from qsls.pipeline.sim.px4 import US, frd_to_flu, ned_to_enu, quat_ned_frd_to_enu_flu
from qsls.pipeline.sim.px4log import Identity, px4_log

COMMANDS = "/mavros/setpoint_raw/attitude"
"""The attitude setpoint's topic (the controller's own, one per tick, before mavros'
``thrust_scaling``)."""
REFERENCE = "/qsls/reference"
"""The reference's topic (the controller's own, a ``setpoint_raw/local``-style message)."""
BAG_FORMAT = "ros1"


def _vectors(data: Mapping[str, np.ndarray], name: str) -> np.ndarray:
    return ned_to_enu(np.asarray(data[name], dtype=float).reshape(-1, 3))


def _quaternions(data: Mapping[str, np.ndarray], name: str) -> np.ndarray:
    q = np.asarray(data[name], dtype=float).reshape(-1, 4)
    return quat_ned_frd_to_enu_flu(q) if len(q) else np.zeros((0, 4))


def mavros_log(
    flight: FlightLog, options: SimOptions, seed: int, identity: Identity
) -> tuple[list[Stream], dict[str, Any]]:
    """The bag's streams and the clock truth (as
    :func:`qsls.pipeline.sim.simulate.ulog_streams`', on the ROS clock) with the ULog's
    ``px4`` block (module docstring)."""
    content, px4 = px4_log(flight, options, seed, identity)
    lo = options.log
    start_ns = round(lo.vio_clock_start_s * NS)
    boot_us = int(px4["boot_us"])
    topics = {t.name: t.data for t in content.topics}

    def ros_ns(data: Mapping[str, np.ndarray], name: str = "timestamp") -> np.ndarray:
        return start_ns + (np.asarray(data[name], dtype=np.int64) - boot_us) * US

    vio = topics["vehicle_visual_odometry"]
    q_vio = _quaternions(vio, "q")
    odometry = OdometryStream(
        topic=lo.vio_topic,
        header_ns=ros_ns(vio, "timestamp_sample"),
        log_ns=ros_ns(vio),
        position=_vectors(vio, "position"),
        orientation=q_vio,
        linear_velocity=world_to_body(q_vio, _vectors(vio, "velocity")),
        angular_velocity=frd_to_flu(np.asarray(vio["angular_velocity"], dtype=float)),
        frame_id=lo.vio_frame_id,
        child_frame_id=lo.vio_child_frame_id,
    )
    mc = topics["vehicle_mocap_odometry"]
    mocap = PoseStream(
        topic=lo.mocap_topic,
        header_ns=ros_ns(mc, "timestamp_sample"),
        log_ns=ros_ns(mc),
        position=_vectors(mc, "position"),
        orientation=_quaternions(mc, "q"),
        msgtype=f"geometry_msgs/msg/{lo.mocap_msgtype}",
        frame_id=lo.mocap_frame_id,
        child_frame_id=lo.mocap_child_frame_id,
    )
    att = topics["vehicle_attitude_setpoint"]
    t_att = ros_ns(att)
    commands = AttitudeTargetStream(
        topic=COMMANDS,
        header_ns=t_att,
        log_ns=t_att,
        orientation=_quaternions(att, "q_d"),
        thrust=-np.asarray(att["thrust_body"], dtype=float).reshape(-1, 3)[:, 2],
    )
    traj = topics["trajectory_setpoint"]
    t_ref = ros_ns(traj)
    reference = PositionTargetStream(
        topic=REFERENCE,
        header_ns=t_ref,
        log_ns=t_ref,
        position=_vectors(traj, "position"),
        velocity=_vectors(traj, "velocity"),
        acceleration=_vectors(traj, "acceleration"),
        yaw=0.5 * np.pi - np.asarray(traj["yaw"], dtype=float),
    )
    truth = {
        "time_offset_s": 0.0,
        "vio_frame": {"yaw_rad": 0.0, "translation": [0.0, 0.0, 0.0]},
        "vio_clock_start_ns": int(start_ns),
        "vio_topic": lo.vio_topic,
        "mocap_topic": lo.mocap_topic,
        "mocap_msgtype": mocap.msgtype,
        "vio_rate_hz": options.vio.rate_hz,
        "mocap_rate_hz": options.mocap.rate_hz,
        "vio_messages": len(odometry),
        "mocap_messages": len(mocap),
        "mavros": {"commands_topic": COMMANDS, "reference_topic": REFERENCE},
        "px4": px4,
    }
    return [odometry, mocap, commands, reference], truth
