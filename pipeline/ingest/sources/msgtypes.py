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

TUM = "text/tum"
"""A TUM trajectory file, as the stream's type (:mod:`.text`)."""
EUROC = "text/euroc-csv"
"""A EuRoC ground-truth csv, as the stream's type (:mod:`.text`)."""

_TF_MSG = "geometry_msgs/TransformStamped[] transforms\n"


def typestore(ros1: bool) -> Any:
    """rosbags' typestore: ROS1 Noetic (plus ``tf2_msgs/msg/TFMessage``) or ROS2 Humble."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if TF not in ts.types:
        ts.register(get_types_from_msg(_TF_MSG, TF))
    return ts


def normalize_type(name: str) -> str:
    """``pkg/Type`` -> ``pkg/msg/Type`` (ROS2 naming, as rosbags uses)."""
    parts = name.strip("/").split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return "/".join(parts)
