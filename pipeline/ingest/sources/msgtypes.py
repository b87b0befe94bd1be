"""The ROS message types qsls reads and writes, by their ROS 2 names, and rosbags' typestore.

Every format's reader and writer imports them from here (docs/ingest.md#formats): a name
spelled once, whatever the bag format.
"""

from __future__ import annotations

from typing import Any

ODOMETRY = "nav_msgs/msg/Odometry"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
POSE_COV = "geometry_msgs/msg/PoseWithCovarianceStamped"
TRANSFORM = "geometry_msgs/msg/TransformStamped"
TF = "tf2_msgs/msg/TFMessage"
IMAGE = "sensor_msgs/msg/Image"
POSE_TYPES = (POSE_STAMPED, POSE_COV, TRANSFORM, ODOMETRY, TF)
ATTITUDE_TARGET = "mavros_msgs/msg/AttitudeTarget"
"""mavros' attitude setpoint (``/mavros/setpoint_raw/attitude`` and its echo
``target_attitude``): the FLU body in ENU and a normalized thrust (:mod:`.mavros`)."""
POSITION_TARGET = "mavros_msgs/msg/PositionTarget"
"""mavros' local position setpoint (``/mavros/setpoint_raw/local``), ENU."""

TUM = "text/tum"
"""A TUM trajectory file, as the stream's type (:mod:`.text`)."""
EUROC = "text/euroc-csv"
"""A EuRoC ground-truth csv, as the stream's type (:mod:`.text`)."""

_TF_MSG = "geometry_msgs/TransformStamped[] transforms\n"

# mavros_msgs' definitions as mavros ships them (ROS1 and ROS2 alike), constants in their
# order: a ROS1 bag's md5sum is computed from them
_ATTITUDE_TARGET_MSG = """\
std_msgs/Header header

uint8 type_mask
uint8 IGNORE_ROLL_RATE = 1
uint8 IGNORE_PITCH_RATE = 2
uint8 IGNORE_YAW_RATE = 4
uint8 IGNORE_THRUST = 64
uint8 IGNORE_ATTITUDE = 128

geometry_msgs/Quaternion orientation
geometry_msgs/Vector3 body_rate
float32 thrust
"""
_POSITION_TARGET_MSG = """\
std_msgs/Header header

uint8 coordinate_frame
uint8 FRAME_LOCAL_NED = 1
uint8 FRAME_LOCAL_OFFSET_NED = 7
uint8 FRAME_BODY_NED = 8
uint8 FRAME_BODY_OFFSET_NED = 9

uint16 type_mask
uint16 IGNORE_PX = 1
uint16 IGNORE_PY = 2
uint16 IGNORE_PZ = 4
uint16 IGNORE_VX = 8
uint16 IGNORE_VY = 16
uint16 IGNORE_VZ = 32
uint16 IGNORE_AFX = 64
uint16 IGNORE_AFY = 128
uint16 IGNORE_AFZ = 256
uint16 FORCE = 512
uint16 IGNORE_YAW = 1024
uint16 IGNORE_YAW_RATE = 2048

geometry_msgs/Point position
geometry_msgs/Vector3 velocity
geometry_msgs/Vector3 acceleration_or_force
float32 yaw
float32 yaw_rate
"""
_EXTRA = {TF: _TF_MSG, ATTITUDE_TARGET: _ATTITUDE_TARGET_MSG, POSITION_TARGET: _POSITION_TARGET_MSG}
"""Types registered beyond the store's own (:func:`typestore`)."""


def typestore(ros1: bool) -> Any:
    """rosbags' typestore: ROS1 Noetic or ROS2 Humble, plus ``tf2_msgs/msg/TFMessage``
    (ROS1) and mavros' ``AttitudeTarget`` and ``PositionTarget``, which neither store has."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    for name, msg in _EXTRA.items():
        if name not in ts.types:
            ts.register(get_types_from_msg(msg, name))
    return ts


def normalize_type(name: str) -> str:
    """``pkg/Type`` -> ``pkg/msg/Type`` (ROS2 naming, as rosbags uses)."""
    parts = name.strip("/").split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return "/".join(parts)
