"""PX4's topics and field names, generation by generation, and its frame codes.

Two message formats carry a pose (docs/ingest.md#px4-ulog):

- ``vehicle_odometry`` (topics ``vehicle_visual_odometry``, ``vehicle_mocap_odometry``,
  ``vehicle_odometry``, ``estimator_odometry``): PX4 >= 1.14 logs ``position[3]``, ``q[4]``,
  ``velocity[3]`` with ``pose_frame`` (1 NED, 2 FRD) and ``velocity_frame`` (1 NED, 2 FRD,
  3 BODY_FRD); older PX4 logs ``x, y, z``, ``q[4]``, ``vx, vy, vz`` with ``local_frame``
  (0 NED, 1 FRD, 2 other) and ``velocity_frame`` (0 NED, 1 FRD, 2 other, 3 BODY_FRD); the
  oldest no frame field (NED).
- ``vehicle_local_position`` (topics ``vehicle_local_position``,
  ``vehicle_local_position_groundtruth``, ``estimator_local_position``): ``x, y, z``,
  ``vx, vy, vz`` (NED), the heading ``heading`` (older: ``yaw``), no quaternion.

A format is recognized by its fields, not its name, so a topic of another name that holds
one of them (a ``--vio-topic`` of the user's own) is read the same way.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

ODOMETRY = "vehicle_odometry"
LOCAL_POSITION = "vehicle_local_position"

ODOMETRY_TOPICS = (
    "vehicle_visual_odometry",
    "vehicle_mocap_odometry",
    "vehicle_odometry",
    "estimator_odometry",
)
LOCAL_POSITION_TOPICS = (
    "vehicle_local_position",
    "vehicle_local_position_groundtruth",
    "estimator_local_position",
)
DEFAULT_VIO_TOPIC = "vehicle_visual_odometry"
DEFAULT_TRUTH_TOPIC = "vehicle_mocap_odometry"

ATTITUDE = "vehicle_attitude"
ATTITUDE_GROUNDTRUTH = "vehicle_attitude_groundtruth"
ATTITUDE_SETPOINT = "vehicle_attitude_setpoint"
HOVER_THRUST_ESTIMATE = "hover_thrust_estimate"
TRAJECTORY_SETPOINT = "trajectory_setpoint"
HOVER_PARAM = "MPC_THR_HOVER"
THR_MDL_PARAM = "THR_MDL_FAC"

MSGTYPE_PREFIX = "px4/"
"""A ULog stream's ``Trajectory.msgtype`` is this and its format (``px4/vehicle_odometry``);
such a stream's velocity is in its world frame (ENU)."""

# ---- frame codes: which rows are world-fixed (NED, or FRD: treated as NED) or body FRD
UNKNOWN, NED, FRD, BODY_FRD = 0, 1, 2, 3
"""The reader's own codes for a message's frame (PX4's differ by generation: below)."""
POSE_FRAMES = {
    "pose_frame": {1: NED, 2: FRD},  # PX4 >= 1.14 (0: unknown)
    "local_frame": {0: NED, 1: FRD},  # older (2: other)
}
VELOCITY_FRAMES = {
    "pose_frame": {1: NED, 2: FRD, 3: BODY_FRD},  # keyed by the generation's pose field
    "local_frame": {0: NED, 1: FRD, 3: BODY_FRD},
}

# ---- field names, newest generation first
POSITION_FIELDS = (("position[0]", "position[1]", "position[2]"), ("x", "y", "z"))
VELOCITY_FIELDS = (("velocity[0]", "velocity[1]", "velocity[2]"), ("vx", "vy", "vz"))
QUATERNION_FIELDS = ("q[0]", "q[1]", "q[2]", "q[3]")
HEADING_FIELDS = ("heading", "yaw")
ACCELERATION_FIELDS = (
    ("acceleration[0]", "acceleration[1]", "acceleration[2]"),
    ("acc_x", "acc_y", "acc_z"),
)
Q_D_FIELDS = ("q_d[0]", "q_d[1]", "q_d[2]", "q_d[3]")
THRUST_BODY_FIELDS = ("thrust_body[0]", "thrust_body[1]", "thrust_body[2]")


def first_present(
    names: Iterable[str], groups: Iterable[tuple[str, ...]]
) -> tuple[str, ...] | None:
    """The first group of field names all in ``names`` (generations newest first), or None."""
    have = set(names)
    return next((g for g in groups if set(g) <= have), None)


def format_kind(fields: Iterable[str]) -> str | None:
    """:data:`ODOMETRY` or :data:`LOCAL_POSITION` for a format holding those fields (flattened
    as pyulog names them: ``position[0]``, ``q[0]``, ``x``), else None."""
    have = set(fields)
    pos = first_present(have, POSITION_FIELDS)
    if pos is None:
        return None
    if set(QUATERNION_FIELDS) <= have:
        return ODOMETRY
    if {"vx", "vy", "vz"} <= have and pos == ("x", "y", "z"):
        return LOCAL_POSITION
    return None


def frame_field(fields: Mapping[str, object] | Iterable[str]) -> str | None:
    """The odometry generation's pose-frame field (``pose_frame``, ``local_frame``), or None
    (the oldest: NED throughout)."""
    have = set(fields)
    return next((f for f in POSE_FRAMES if f in have), None)
