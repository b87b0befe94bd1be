"""The options of ``qsls ingest`` (and of the ``ingest:`` section of a run config), apart from
the stage: this module imports only pydantic, so ``qsls run`` validates a run config
(:class:`qsls.pipeline.run.runner.RunConfig`) without loading the bag readers, scipy or
pandas. :mod:`qsls.pipeline.ingest.stage` re-exports it."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, field_validator, model_validator

from qsls.pipeline.core.config import Options


class IngestOptions(Options):
    """Options of ``qsls ingest`` (defaults are the built-in defaults)."""

    vio_topic: str | None = None
    """VIO topic (nav_msgs/Odometry, or a pose topic); default: chosen when unambiguous. In a
    PX4 ULog: NAME[:INSTANCE] of an odometry or local position topic (default
    vehicle_visual_odometry)."""
    truth_topic: str | None = None
    """Ground-truth topic (PoseStamped, PoseWithCovarianceStamped, TransformStamped, Odometry,
    or a TF topic with ``truth_frame``); default: chosen when unambiguous. In a PX4 ULog:
    NAME[:INSTANCE] (default vehicle_mocap_odometry)."""
    vio: Path | None = None
    """File holding the VIO stream (bag, PX4 ULog, TUM, EuRoC csv); default: the sources
    given."""
    truth: Path | None = None
    """File holding the truth stream (bag, PX4 ULog, TUM, EuRoC csv); default: the sources
    given."""
    dt: float = Field(0.1, gt=0)
    """Resampling period (s)."""
    align: Literal["4dof", "se3", "none"] = "4dof"
    """Frame alignment of the VIO to the truth: 4dof (yaw + translation), se3 (full SE(3)), or
    none."""
    time_offset: Literal["auto"] | float = "auto"
    """Seconds added to truth stamps to reach the VIO clock, or ``auto`` (estimated)."""
    vio_velocity_frame: Literal["body", "world"] = "body"
    """Frame of the Odometry twist: body (ROS convention) or world (VINS-style)."""
    stamp: Literal["header", "log"] = "header"
    """Time of a message: its header stamp or the bag's log time."""
    max_truth_accel: float = Field(100.0, gt=0)
    """A truth interval implying a larger acceleration (m/s^2) is a motion-capture
    discontinuity: turned into a gap of ``max_gap`` (never interpolated across) and counted
    (``discontinuities``); 100 m/s^2 is 10 g, beyond any flight."""
    max_gap: float = Field(0.25, gt=0)
    """Never interpolate across a gap longer than this (s)."""
    truth_frame: str | None = None
    """PARENT/CHILD transform of a TF topic; default: none (a TF-only bag lists them)."""
    export_tum: bool = False
    """Also write both aligned trajectories as TUM files (for evo)."""
    max_time_offset: float = Field(2.0, gt=0)
    """Search range of ``time_offset: auto`` (s)."""
    min_overlap: float = Field(3.0, gt=0)
    """Least common time of the two streams (s)."""
    velocity_window: float = Field(0.1, gt=0)
    """Window of the smoothing differentiator (s)."""
    drop_nonfinite: bool = False
    """Skip messages with NaN/inf values instead of stopping."""
    mass: float | None = Field(None, gt=0)
    """The vehicle's mass (kg). Given, ingest also reads the controller's commands (a PX4
    ULog's attitude and trajectory setpoints, or a mavros bag's) back to the model's input and
    writes the flight's tick log, ``ticks.parquet`` (docs/vehicle.md); no log holds it."""
    hover_thrust: float | None = Field(None, gt=0, lt=1)
    """The normalized thrust that hovers the vehicle, in the commands' units (PX4: its
    ``hover_thrust_estimate`` where valid, else ``MPC_THR_HOVER``, is read from a ULog; a
    mavros bag needs it given); with ``mass`` only."""
    decoder: Literal["fast", "deserializer"] = "fast"
    """Message decoding: the fast field reader, or rosbags' full deserializer (a check)."""
    commands_topic: str | None = None
    """A bag's attitude setpoints (mavros_msgs/AttitudeTarget), with ``mass``; default:
    /mavros/setpoint_raw/attitude (the controller's own), else
    /mavros/setpoint_raw/target_attitude."""
    reference: str | None = None
    """The reference the controller tracked, stated (``circle:radius=1,height=1,period=5``),
    for a log without its position setpoints: sampled at each command from the first (0 s), as
    the controller started it; with ``mass`` only (default: the log's setpoints)."""
    reference_topic: str | None = None
    """A bag's reference (mavros_msgs/PositionTarget, one per tick), with ``mass``; default:
    /qsls/reference, else /mavros/setpoint_raw/local."""
    feedforward: Literal["sampled", "hover", "attitude"] = "sampled"
    """With ``reference``: how the controller's feedforward followed from it: ``sampled``, the
    reference's acceleration at each command (a flight stack's setpoint); ``hover`` or
    ``attitude``, the model's (the step mean of that plant's inverse, as qsls's simulator and
    PX4 stand-in fly: docs/guarantee.md, Disturbance in deviation coordinates)."""

    @model_validator(mode="after")
    def _commands_need_the_mass(self) -> IngestOptions:
        given = [k for k in ("hover_thrust", "commands_topic", "reference_topic", "reference")
                 if getattr(self, k) is not None]  # fmt: skip
        if given and self.mass is None:
            raise ValueError(
                f"{', '.join(given)} reads the controller's commands, which needs the vehicle's "
                "mass: give --mass KG (docs/vehicle.md)"
            )
        return self

    @field_validator("truth_frame")
    @classmethod
    def _frame(cls, v: str | None) -> str | None:
        if v is not None and (v.count("/") < 1 or not all(v.strip("/").split("/", 1))):
            raise ValueError("expected PARENT/CHILD, e.g. world/body")
        return v.strip("/") if v else v
