"""The replay's output: a ROS 2 MCAP written with rosbags (``rosbag2.Writer``, MCAP storage).

Topics:

- the commands as ``mavros_msgs/msg/AttitudeTarget`` (the definition is registered with
  rosbags' typesys, it is not in the stock typestores): attitude quaternion in the z-up (ENU)
  world, ``type_mask`` 7 (body rates ignored), ``thrust`` normalized as mavros expects
  (``hover_thrust * thrust / (m g)``);
- the deviations as ``std_msgs/msg/Float64MultiArray``: ``[y - r (6), u (3)]`` per tick,
  doubles, so a reader gets the controller's exact ``u``;
- the absolute command as ``geometry_msgs/msg/Vector3Stamped``: ``[pitch, roll, thrust]``
  (paper signs, rad, rad, N).

Stamps: header and log time are the tick's stamp on the source's clock. The replay's report
(limits, gaps, controller) goes into the bag's metadata (``custom_data.qsls_replay``, JSON).
The file appears atomically: written in a temporary folder beside ``path``, then renamed.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.core.locks import make_temporary

ATTITUDE_TARGET = "mavros_msgs/msg/AttitudeTarget"
MULTI_ARRAY = "std_msgs/msg/Float64MultiArray"
VECTOR3_STAMPED = "geometry_msgs/msg/Vector3Stamped"
IGNORE_BODY_RATES = 1 | 2 | 4

ATTITUDE_TARGET_MSG = """\
# Message for SET_ATTITUDE_TARGET (mavros_msgs)
std_msgs/Header header

uint8 type_mask
uint8 IGNORE_ROLL_RATE = 1 # body_rate.x
uint8 IGNORE_PITCH_RATE = 2 # body_rate.y
uint8 IGNORE_YAW_RATE = 4 # body_rate.z
uint8 IGNORE_THRUST = 64
uint8 IGNORE_ATTITUDE = 128 # orientation field

geometry_msgs/Quaternion orientation
geometry_msgs/Vector3 body_rate
float32 thrust
"""


def typestore() -> Any:
    """ROS 2 Humble types plus ``mavros_msgs/msg/AttitudeTarget``."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    ts.register(get_types_from_msg(ATTITUDE_TARGET_MSG, ATTITUDE_TARGET))
    return ts


@dataclass(frozen=True)
class Topics:
    command: str = "/mavros/setpoint_raw/attitude"
    deviation: str = "/qsls/deviation"
    absolute: str = "/qsls/command"
    frame_id: str = "map"


@dataclass(frozen=True)
class Ticks:
    """What the replay commanded, one row per tick."""

    stamp_ns: np.ndarray  # (n,) int64
    y_dev: np.ndarray  # (n, 6) y - r
    u: np.ndarray  # (n, 3) deviation from hover + feedforward
    u_abs: np.ndarray  # (n, 3) [pitch, roll, thrust] paper signs
    thrust: np.ndarray  # (n,) N
    q: np.ndarray  # (n, 4) x y z w
    thrust_normalized: np.ndarray  # (n,) mavros AttitudeTarget.thrust


def write_mcap(path: Path, ticks: Ticks, topics: Topics, report_json: str) -> Path:
    """Write ``ticks`` as a ROS 2 MCAP file at ``path`` (module docstring)."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    path = Path(path)
    ts = typestore()
    t = ts.types
    Time, Header = t["builtin_interfaces/msg/Time"], t["std_msgs/msg/Header"]
    Quat, Vec3 = t["geometry_msgs/msg/Quaternion"], t["geometry_msgs/msg/Vector3"]
    Att, Multi = t[ATTITUDE_TARGET], t[MULTI_ARRAY]
    Layout, Dim = t["std_msgs/msg/MultiArrayLayout"], t["std_msgs/msg/MultiArrayDimension"]
    V3S = t[VECTOR3_STAMPED]
    layout = Layout(dim=[Dim(label="y_minus_r[6],u[3]", size=9, stride=9)], data_offset=0)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmpdir = make_temporary(path)
    bag = tmpdir / "replay"
    try:
        w = Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP)
        w.set_custom_data("qsls_replay", report_json)
        with w:
            c_cmd = w.add_connection(topics.command, ATTITUDE_TARGET, typestore=ts)
            c_dev = w.add_connection(topics.deviation, MULTI_ARRAY, typestore=ts)
            c_abs = w.add_connection(topics.absolute, VECTOR3_STAMPED, typestore=ts)
            zero = Vec3(x=0.0, y=0.0, z=0.0)
            for k, ns in enumerate(ticks.stamp_ns.tolist()):
                sec, nsec = divmod(int(ns), 1_000_000_000)
                hdr = Header(stamp=Time(sec=sec, nanosec=nsec), frame_id=topics.frame_id)
                qx, qy, qz, qw = (float(v) for v in ticks.q[k])
                att = Att(
                    header=hdr,
                    type_mask=IGNORE_BODY_RATES,
                    orientation=Quat(x=qx, y=qy, z=qz, w=qw),
                    body_rate=zero,
                    thrust=float(ticks.thrust_normalized[k]),
                )
                w.write(c_cmd, ns, bytes(ts.serialize_cdr(att, ATTITUDE_TARGET)))
                data = np.concatenate([ticks.y_dev[k], ticks.u[k]]).astype(np.float64)
                dev = Multi(layout=layout, data=data)
                w.write(c_dev, ns, bytes(ts.serialize_cdr(dev, MULTI_ARRAY)))
                a = ticks.u_abs[k]
                v3 = V3S(header=hdr, vector=Vec3(x=float(a[0]), y=float(a[1]), z=float(a[2])))
                w.write(c_abs, ns, bytes(ts.serialize_cdr(v3, VECTOR3_STAMPED)))
        os.replace(bag / "replay.mcap", path)
    finally:
        shutil.rmtree(tmpdir, ignore_errors=True)
    return path
