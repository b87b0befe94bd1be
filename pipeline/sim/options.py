"""The options of ``qsls simulate`` (and of the ``simulate:`` section of a run config), apart
from the simulator: the vehicle, the reference, the controller, the VIO emulator's parameters,
the motion capture, the crash limits and the logs. This module imports only pydantic and light
qsls modules (the plant's constants, the reference's options, the PD gains), so ``qsls run``
validates a run config (:class:`qsls.pipeline.run.runner.RunConfig`) without loading RotorPy,
scipy or pandas. The simulator's modules re-export them where they were defined:
:mod:`qsls.pipeline.sim.vio` (:class:`VioParams` and its parts, :func:`scaled_ridges`),
:mod:`qsls.pipeline.sim.vehicle`, :mod:`qsls.pipeline.sim.controllers`,
:mod:`qsls.pipeline.sim.mocap`, :mod:`qsls.pipeline.sim.closedloop` and
:mod:`qsls.pipeline.sim.simulate`."""

from __future__ import annotations

import math
from typing import Any, Literal, get_args

from pydantic import (
    Field,
    SerializerFunctionWrapHandler,
    field_validator,
    model_serializer,
    model_validator,
)

from qsls.pipeline.control.pdgain import PDGains
from qsls.pipeline.core.config import Duration, Options, Seed
from qsls.pipeline.core.references import ReferenceOptions
from qsls.pipeline.sim.camera.options import CameraOptions

Six = tuple[float, float, float, float, float, float]

Perception = Literal["regular", "degraded"]
"""A perception condition: regular, or degraded (less light and texture)."""
PERCEPTIONS: tuple[Perception, ...] = get_args(Perception)


class Ridge(Options):
    """A smooth step ``A tanh((n . p - offset) / width)`` across the floor."""

    normal_deg: float = 0.0
    """Direction of the ridge's normal in the horizontal plane (degrees from +x)."""
    offset: float = 0.0
    """Signed distance of the ridge's centre line from the origin along the normal (m)."""
    width: float = Field(0.2, gt=0)
    """Half-width of the steep part (m); the largest slope is amplitude / width."""
    amplitude: Six = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    """Step half-height per error component ``e_px .. e_vz`` (m, m/s)."""


class Ripple(Options):
    """A gentle undulation ``A sin(kx px + ky py + phase)``."""

    wavevector: tuple[float, float] = (2.0, 1.0)
    """``(kx, ky)`` in rad/m."""
    phase: float = 0.0
    amplitude: Six = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


class MappedRegion(Options):
    """Where the estimator knows the scene: beyond ``radius`` (m) from ``center`` its position
    estimate takes a scale error that grows with the distance outside,
    ``slope * max(0, |p_xy - c| - radius)`` along the outward direction (a map built on the
    design flights, extrapolated: :mod:`qsls.pipeline.sim.vio`). It makes the error grow with
    the distance from the training states, so range flights measure ``S``."""

    center: tuple[float, float] = (0.0, 0.0)
    radius: float = Field(1.5, gt=0)
    slope: float = Field(0.05, ge=0, le=1)
    """Metres of position error per metre outside the region."""


class VioFault(Options):
    """A perception fault injected into the estimate (to test the onboard monitor and the
    runtime-assured mode, docs/monitor.md): from ``start_s`` on, ``bias`` is added to every
    VIO sample's error ``e`` (emulator or camera loop), so ``y = x + e + bias``."""

    start_s: float = Field(0.0, ge=0)
    """Simulation time (s) of the first faulty sample."""
    bias: Six = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    """The step added to ``e_px .. e_vz`` (m, m/s)."""


class PerceptionLevel(Options):
    """Light level and texture richness, each in (0, 1] (1 = ideal)."""

    light: float = Field(1.0, gt=0, le=1)
    texture: float = Field(1.0, gt=0, le=1)


# The bias field's ridges as first designed: (normal_deg, offset, width, amplitude). Each
# feeds the position error along its own normal and the velocity error across it, so that on
# the default circle the tangential position error and the radial velocity error average
# out over a lap: the bias does not look like a rotation of the frame or a clock shift (both
# of which ingest must recover). The x = -0.35 m ridge is crossed twice per lap (not by the
# approach from the centre to the circle's first point); y = -0.3 m likewise; the diagonal
# one makes the height and vertical-velocity error.
FIRST_RIDGES: tuple[tuple[float, float, float, Six], ...] = (
    (0.0, -0.35, 0.2, (0.04, 0.0, 0.0, 0.0, 0.025, 0.0)),
    (90.0, -0.3, 0.25, (0.0, 0.04, 0.0, 0.03, 0.0, 0.0)),
    (45.0, 0.6, 0.3, (0.0, 0.0, 0.015, 0.0, 0.0, 0.015)),
)
# Calibrated against real VIO (benchmarks/bench_rpe.py --scan): the position steps of the
# first design are scaled so that the 1 s RPE's growth with speed (fastest over slowest third
# of 1 s windows: 1.23-1.83x on real EuRoC VIO) falls in the real range on every emulated
# flight of that benchmark; the velocity steps by the one common factor that makes the
# largest row of L (now e_vy: 0.0357 / 0.2 + ripples 0.0105 + kappa 0.02) 0.209 again, so
# the Lipschitz constant is the first design's.
RIDGE_POSITION_SCALE = 0.35
RIDGE_VELOCITY_SCALE = 1.428


def scaled_ridges(position: float, velocity: float) -> list[Ridge]:
    """:data:`FIRST_RIDGES` with the position steps times ``position`` and the velocity steps
    times ``velocity`` (rounded to 1e-9 m, m/s)."""

    def scale(a: Six) -> Six:
        p, v = position, velocity
        return (
            round(a[0] * p, 9), round(a[1] * p, 9), round(a[2] * p, 9),
            round(a[3] * v, 9), round(a[4] * v, 9), round(a[5] * v, 9),
        )  # fmt: skip

    return [
        Ridge(normal_deg=n, offset=c, width=w, amplitude=scale(amp))
        for n, c, w, amp in FIRST_RIDGES
    ]


def _default_ridges() -> list[Ridge]:
    return scaled_ridges(RIDGE_POSITION_SCALE, RIDGE_VELOCITY_SCALE)


def _default_ripples() -> list[Ripple]:
    return [
        Ripple(wavevector=(2.0, 1.0), phase=0.3, amplitude=(0.003, 0.003, 0.002, 0.0, 0.0, 0.0)),
        Ripple(wavevector=(-1.0, 2.5), phase=1.1, amplitude=(0.0, 0.0, 0.0, 0.003, 0.003, 0.003)),
    ]


class VioParams(Options):
    """Every parameter of the VIO emulator (all in the config; see :mod:`qsls.pipeline.sim.vio`)."""

    # switches
    bias: bool = True
    drift: bool = True
    noise: bool = True
    outliers: bool = True
    blur: bool = True
    motion_drift: bool = True
    feature_loss: bool = True
    perception: Perception = "regular"
    """Perception conditions: regular, or degraded (less light and texture)."""
    kind: Literal["emulator", "camera"] = "emulator"
    """Where the estimate comes from: ``emulator`` (the error model of
    :mod:`qsls.pipeline.sim.vio`) or ``camera`` (a rendered camera, an IMU and an MSCKF:
    :mod:`qsls.pipeline.sim.camera`, parameters in ``camera``; ``perception`` and the presets'
    light and texture keep their meaning, the emulator's error-model parameters are not used)."""
    camera: CameraOptions = CameraOptions()
    """The camera loop's parameters (``kind: camera``)."""
    fault: VioFault | None = None
    """A step fault added to the estimate from a given time (none by default)."""

    rate_hz: float = Field(100.0, ge=30.0, le=200.0)
    """VIO output rate (Hz), 30 to 200 like real VIO pipelines."""

    # perception presets
    regular: PerceptionLevel = PerceptionLevel(light=1.0, texture=1.0)
    degraded: PerceptionLevel = PerceptionLevel(light=0.35, texture=0.45)

    # bias field
    ridges: list[Ridge] = Field(default_factory=_default_ridges)
    ripples: list[Ripple] = Field(default_factory=_default_ripples)
    region: MappedRegion | None = None
    """The region the estimator knows (None: the error does not depend on where the vehicle
    is beyond the bias field)."""
    velocity_scale: tuple[float, float, float] = (0.02, 0.02, 0.01)
    """Velocity scale-factor error ``kappa`` per axis (fraction)."""
    bias_light_gain: float = Field(1.0, ge=0)
    """Bias grows by ``1 + bias_light_gain (1 - light)`` in poor light."""

    # drift
    drift_fraction: float = Field(0.002, ge=0)
    """Systematic position drift per metre travelled (m/m)."""
    drift_walk: float = Field(0.002, ge=0)
    """Random-walk drift density (m per sqrt(m) travelled)."""
    drift_vertical: float = Field(0.3, ge=0)
    """Scale of the vertical component of the drift direction."""

    # noise
    noise_position: float = Field(0.004, ge=0)
    """Position noise std (m) with ideal texture and light."""
    noise_velocity: float = Field(0.015, ge=0)
    """Velocity noise std (m/s) with ideal texture and light."""
    noise_gain: float = Field(4.0, ge=0)
    """Noise grows by ``1 + noise_gain (1 - light * texture(p))``."""
    texture_wavelength: float = Field(1.5, gt=0)
    """Wavelength of the floor's texture pattern (m)."""
    texture_patch_center: tuple[float, float] = (-0.6, 0.6)
    """Centre of a poorly textured patch on the floor (m); the circle passes over it."""
    texture_patch_radius: float = Field(0.35, gt=0)
    texture_patch_depth: float = Field(0.5, ge=0, le=1)

    # outliers
    outlier_prob: float = Field(0.003, ge=0, le=1)
    """Per-sample probability of a velocity outlier in ideal conditions."""
    outlier_min: float = Field(0.3, ge=0)
    outlier_max: float = Field(1.0, ge=0)

    # motion blur
    blur_exposure_s: float = Field(0.005, gt=0)
    """Camera exposure in ideal light (s); ``/ light`` in poor light."""
    blur_exposure_max_s: float = Field(0.02, gt=0)
    """Longest exposure (s)."""
    blur_focal_px: float = Field(460.0, gt=0)
    """Focal length (px; EuRoC's cameras: about 460)."""
    blur_min_height: float = Field(0.3, gt=0)
    """Height below which the translation blur stops growing (m)."""
    blur_noise_position: float = Field(0.0015, ge=0)
    """Extra position noise std per pixel of blur (m/px)."""
    blur_noise_velocity: float = Field(0.005, ge=0)
    """Extra velocity noise std per pixel of blur (m/s/px)."""
    blur_outlier_rate: float = Field(0.0005, ge=0)
    """Extra velocity-outlier probability per sample per pixel of blur."""

    # drift with motion
    drift_per_radian: float = Field(0.002, ge=0)
    """Systematic position drift per radian turned (m/rad)."""
    drift_walk_radian: float = Field(0.002, ge=0)
    """Random-walk drift density per radian turned (m per sqrt(rad))."""
    drift_speed_gain: float = Field(1.0, ge=0)
    """Per-metre drift grows by ``1 + drift_speed_gain * speed`` (per m/s)."""

    # feature loss
    loss_rate_threshold: float = Field(3.0, gt=0)
    """Body rate above which tracking can be lost (rad/s)."""
    loss_accel_threshold: float = Field(8.0, gt=0)
    """Acceleration above which tracking can be lost (m/s^2)."""
    loss_rate_hz: float = Field(0.5, ge=0)
    """Bursts per second spent above a threshold, in ideal texture and light."""
    loss_texture_gain: float = Field(4.0, ge=0)
    """Burst rate grows by ``1 + loss_texture_gain (1 - light * texture(p))``."""
    loss_duration_s: tuple[float, float] = (0.2, 0.6)
    """Burst length range (s)."""
    loss_position: float = Field(0.1, ge=0)
    """Peak position error of a burst (m)."""
    loss_velocity: float = Field(0.3, ge=0)
    """Peak velocity error of a burst (m/s)."""

    @model_serializer(mode="wrap")
    def _dump(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        """An emulator's options dump without ``kind`` and ``camera``, as before the camera
        loop existed: the emulator's artifacts (manifest, truth.json) stay byte-identical."""
        out: dict[str, Any] = handler(self)
        if self.kind == "emulator":
            out.pop("kind", None)
            out.pop("camera", None)
        if self.fault is None:
            out.pop("fault", None)
        return out

    @field_validator("outlier_max")
    @classmethod
    def _max_ge_min(cls, v: float, info: Any) -> float:
        lo = info.data.get("outlier_min")
        if lo is not None and v < lo:
            raise ValueError(f"outlier_max ({v}) must be >= outlier_min ({lo})")
        return v

    @field_validator("loss_duration_s")
    @classmethod
    def _duration_ordered(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not 0 < v[0] <= v[1]:
            raise ValueError(f"loss_duration_s {v} must be (min, max) with 0 < min <= max")
        return v

    @property
    def level(self) -> PerceptionLevel:
        """The active perception level (``regular`` or ``degraded`` preset); the camera loop's
        degraded level is the camera's own, ``camera.degraded_light`` / ``degraded_texture``
        (0.15 / 0.25 unless set: the shared preset barely degrades the camera, docs/camera.md),
        each taking the shared preset's where set to None."""
        if self.perception != "degraded":
            return self.regular
        cam = self.camera
        if self.kind == "camera" and (
            cam.degraded_light is not None or cam.degraded_texture is not None
        ):
            return PerceptionLevel(
                light=cam.degraded_light if cam.degraded_light is not None else self.degraded.light,
                texture=cam.degraded_texture
                if cam.degraded_texture is not None
                else self.degraded.texture,
            )
        return self.degraded


class WindOptions(Options):
    """The wind the vehicle flies in (docs/calibration.md#conditions-as-a-stated-family):
    RotorPy's ``ConstantWind`` plus its ``SinusoidWind`` gust, both horizontal, the world
    wind ``w(t) = (speed + gust sin(2 pi gust_hz (t + phase))) [cos d, sin d, 0]`` with ``d``
    = ``direction_deg`` and ``phase`` drawn from the flight's seed. The vehicle's drag acts on
    its airspeed ``v - w`` (``vehicle.aero``). No wind by default (absent from the dump)."""

    speed: float = Field(0.0, ge=0, le=20)
    """Steady horizontal wind speed (m/s)."""
    direction_deg: float = Field(0.0, ge=-360, le=360)
    """Where the wind blows *to*, degrees counter-clockwise from the world's +x."""
    gust: float = Field(0.0, ge=0, le=10)
    """Gust amplitude along the wind's direction (m/s; 0: steady)."""
    gust_hz: float = Field(0.5, gt=0, le=10)
    """Gust frequency (Hz)."""

    @property
    def off(self) -> bool:
        """No wind at all (the vehicle flies in still air)."""
        return self.speed == 0 and self.gust == 0


class VehicleOptions(Options):
    """The simulated vehicle and its integrator."""

    mass: float = Field(0.256, gt=0)
    """Mass (kg); the paper's vehicle weighs 256 g. Other parameters stay those of QUAD_256G."""
    aero: bool = True
    """RotorPy's aerodynamic wrenches (parasitic drag, rotor drag, translational lift)."""
    physics_hz: float = Field(200.0, gt=0)
    """Integration step rate; the attitude loop also runs at this rate."""
    integrator: Literal["rk4", "solve_ivp"] = "rk4"
    """``rk4``: the fast fixed-step loop; ``solve_ivp``: RotorPy's stock ``Multirotor.step``."""
    ivp_rtol: float | None = Field(None, gt=0)
    """``solve_ivp`` only: relative tolerance (None: RotorPy's default RK45 settings)."""
    substeps: int = Field(1, ge=1, le=50)
    """RK4 substeps per physics step (the motor command is held over the step)."""
    max_tilt_deg: float = Field(35.0, gt=0, lt=90)
    """Commanded pitch and roll are clipped to this angle."""
    thrust_constant: float = Field(1.0, ge=0.5, le=1.5)
    """The rotors' true thrust constant relative to the nominal ``k_eta`` (another propeller);
    the flight computer allocates with the nominal one, so the thrust is this times the
    command. Absent from the dump at 1."""
    sag: float = Field(0.0, ge=0, le=0.5)
    """Battery sag: the share of thrust lost by the flight's end for the same command,
    linearly in time (the rotor speeds scale by ``sqrt(1 - sag t / duration)``). Absent
    from the dump at 0."""

    @model_serializer(mode="wrap")
    def _dump(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        """A vehicle's dump without ``thrust_constant`` and ``sag`` at their nominal values,
        as before they existed: every artifact of such a flight stays byte-identical."""
        out: dict[str, Any] = handler(self)
        if self.thrust_constant == 1.0:
            out.pop("thrust_constant", None)
        if self.sag == 0.0:
            out.pop("sag", None)
        return out


class ControllerOptions(Options):
    """Which controller flies, how fast, and on what feedback."""

    kind: str = "se3"
    """``se3``, ``pd``, or the path of a synthesized controller folder (``controller.npz``)."""
    rate_hz: float | None = Field(None, gt=0)
    """Control rate; default: SE3 100 Hz, PD and synthesized controllers 1 / their dt (10 Hz)."""
    feedback: Literal["vio", "truth"] = "vio"
    """What the controller sees: the VIO estimate (as on the real vehicle) or the true state."""
    pd: PDGains = PDGains()
    se3_kp: tuple[float, float, float] = (6.5, 6.5, 15.0)
    """SE3 position gains (RotorPy's defaults)."""
    se3_kd: tuple[float, float, float] = (4.0, 4.0, 9.0)
    se3_backend: Literal["fast", "rotorpy"] = "fast"
    """``rotorpy`` calls ``SE3Control.update``; ``fast`` evaluates the same law (same output)."""
    backend: Literal["python", "c"] = "python"
    """Synthesized filter banks: ``python`` runs the realization (numpy); ``c`` flies the code of
    ``qsls export --target c``, compiled and loaded with ctypes (the PD's static gain stays)."""


class MocapOptions(Options):
    """The motion-capture system (ground truth)."""

    rate_hz: float = Field(120.0, ge=100.0, le=200.0)
    """Sample rate (Hz), 100 to 200 like Vicon/OptiTrack setups."""
    position_noise: float = Field(0.001, ge=0)
    """Position noise std per axis (m)."""
    attitude_noise: float = Field(0.002, ge=0)
    """Attitude noise std per axis (rad)."""


class CrashOptions(Options):
    """When a flight counts as crashed (and ends)."""

    floor_z: float = 0.05
    """Ground contact: true height below this (m)."""
    max_deviation: float = Field(3.0, gt=0)
    """Divergence: any position axis farther than this from the reference (m)."""
    max_tilt_deg: float = Field(80.0, gt=0, le=180)
    """Loss of control: tilt of the body z axis beyond this (degrees)."""


class Px4Options(Options):
    """The PX4 stand-in (docs/simulation.md#the-px4-stand-in): how the controller's command
    reaches the vehicle, and how the estimate and the motion capture reach the controller and
    the log. The defaults change nothing: the paper's interface, every message on time."""

    interface: Literal["paper", "px4"] = "paper"
    """``paper``: the vehicle flies the paper's ``[pitch, roll, thrust]`` (small-angle map);
    ``px4``: the export's exact attitude map to an attitude ``q_d`` and a normalized thrust
    ``hover_estimate * thrust / (m g)``, which the vehicle flies as
    ``T m_true g / hover_thrust``, as PX4 would."""
    hover_thrust: float = Field(0.5, gt=0, lt=1)
    """The vehicle's true hover throttle (PX4's ``MPC_THR_HOVER``)."""
    hover_estimate: float | None = Field(None, gt=0, lt=1)
    """The hover throttle the interface assumes (default: ``hover_thrust``); a wrong one is
    a thrust error the controller sees as a disturbance."""
    thr_mdl_fac: float = Field(0.0, ge=0, le=1)
    """PX4's ``THR_MDL_FAC`` (thrust curve), recorded in the log only."""
    controller_mass: float | None = Field(None, gt=0)
    """The mass the controller and the interface assume (kg; default: ``vehicle.mass``)."""
    estimator_latency_s: float = Field(0.0, ge=0, le=1)
    """Transport latency of each estimate, capture to arrival (s); the controller reads the
    newest estimate that has arrived at its tick."""
    estimator_jitter_s: float = Field(0.0, ge=0, le=0.5)
    """Uniform extra latency in ``[0, jitter]`` per estimate (s, seeded); messages stay in
    order (a later one never arrives before an earlier one)."""
    estimator_drop: float = Field(0.0, ge=0, lt=1)
    """Probability that an estimate never arrives (seeded)."""
    mocap_latency_s: float = Field(0.0, ge=0, le=1)
    """Transport latency of each motion-capture message (s; the log only)."""
    mocap_jitter_s: float = Field(0.0, ge=0, le=0.5)
    """Uniform extra latency in ``[0, jitter]`` per motion-capture message (s, seeded)."""
    mocap_drop: float = Field(0.0, ge=0, lt=1)
    """Probability that a motion-capture message never arrives (seeded)."""
    boot_s: float = Field(20.0, ge=0, le=1_000_000)
    """PX4's boot clock at the flight's ``t = 0`` (s): the log's timestamps are µs since boot."""
    logger_dropouts: int = Field(0, ge=0, le=1000)
    """Logger dropouts in the ULog (each loses 5 to 50 ms of every topic; seeded)."""

    @property
    def estimate(self) -> float:
        """The hover throttle the interface assumes."""
        return self.hover_thrust if self.hover_estimate is None else self.hover_estimate

    @property
    def timed(self) -> bool:
        """Whether the controller reads estimates by their arrival time (the PX4 interface, or
        any latency, jitter or drop); otherwise by capture time, as before the stand-in."""
        return self.interface == "px4" or bool(
            self.estimator_latency_s or self.estimator_jitter_s or self.estimator_drop
        )


class FlightOptions(Options):
    """Everything that shapes one simulated flight."""

    seed: Seed = 0
    """Random seed of the VIO emulator and the logs."""
    duration: Duration | None = None
    """Flight length (s), at most a day (a simulated day takes hours and about 140 MB);
    default: take-off, approach and the reference's laps (ramp / 2 + laps * period: 23 s for
    3 laps of the 5 s circle)."""
    vehicle: VehicleOptions = VehicleOptions()
    reference: ReferenceOptions = ReferenceOptions()
    controller: ControllerOptions = ControllerOptions()
    vio: VioParams = VioParams()
    crash: CrashOptions = CrashOptions()
    px4: Px4Options = Px4Options()
    """The PX4 stand-in: the interface, the hover throttle, the estimate's and the motion
    capture's transport (none by default, and then absent from the options' dump)."""
    wind: WindOptions = WindOptions()
    """The wind (none by default, and then absent from the options' dump)."""
    start_offset: tuple[float, float] = (0.0, 0.0)
    """Where the vehicle starts beside the reference's first point (m, x and y, at its
    height): it flies to the reference from there. (0, 0) by default, on it, and then absent
    from the options' dump."""

    @model_serializer(mode="wrap")
    def _dump(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        """A flight's options dump without ``px4``, ``wind`` and ``start_offset`` when they
        are the default, as before they existed: every artifact of such a flight stays
        byte-identical."""
        out: dict[str, Any] = handler(self)
        if self.px4 == Px4Options():
            out.pop("px4", None)
        if self.wind == WindOptions():
            out.pop("wind", None)
        if self.start_offset == (0.0, 0.0):
            out.pop("start_offset", None)
        return out

    @field_validator("start_offset")
    @classmethod
    def _near(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not all(math.isfinite(c) and abs(c) <= 10.0 for c in v):
            raise ValueError(f"start_offset {list(v)}: each coordinate finite, within 10 m")
        return v

    def flight_duration(self) -> float:
        return (
            float(self.duration) if self.duration is not None else self.reference.natural_duration()
        )


class LogOptions(Options):
    """How the flight is recorded: format, topics, clocks, frames, transport delays."""

    format: Literal["ros1", "ros2-sqlite", "ros2-mcap", "mcap", "ulog", "mavros"] = "ros1"
    """Bag format: ros1, ros2-sqlite, ros2-mcap or mcap; or ulog, the log PX4 writes
    (``flight.ulg``); or mavros, a ROS1 bag as a ROS user with mavros records the PX4 vehicle
    (``flight.bag``: the estimate, the motion capture, the attitude setpoints and the
    reference); both need ``px4.interface: px4``."""
    compression: str | None = None
    """Bag compression (ros1: lz4, bz2; rosbag2: zstd; mcap: zstd, lz4); none by default."""
    vio_topic: str = "/vio/odometry"
    vio_frame_id: str = "odom"
    vio_child_frame_id: str = "base_link"
    mocap_topic: str = "/vicon/quad/pose"
    mocap_msgtype: Literal["PoseStamped", "TransformStamped"] = "PoseStamped"
    mocap_frame_id: str = "world"
    mocap_child_frame_id: str = "quad"
    time_offset_s: float = Field(-0.137, ge=-5.0, le=5.0)
    """Added to motion-capture stamps to put them on the VIO clock (docs/conventions.md#clocks)."""
    vio_clock_start_s: float = Field(1_700_000_000.0, ge=0)
    """VIO clock reading at the start of the flight (s)."""
    vio_delay_s: float = Field(0.020, ge=0)
    """Transport delay from VIO stamp to log time (s)."""
    mocap_delay_s: float = Field(0.005, ge=0)
    delay_jitter_s: float = Field(0.002, ge=0)
    """Uniform extra delay in [0, jitter] per message (seeded)."""
    vio_frame_yaw_deg: float = 35.0
    """Yaw of the VIO world frame in the motion-capture frame (degrees)."""
    vio_frame_translation: tuple[float, float, float] = (0.8, -0.4, 0.05)
    """Origin of the VIO world frame in the motion-capture frame (m)."""


class SimOptions(FlightOptions):
    """``qsls simulate``: the flight (vehicle, reference, controller, VIO) and its logs."""

    mocap: MocapOptions = MocapOptions()
    log: LogOptions = LogOptions()

    @model_validator(mode="after")
    def _ulog_is_px4(self) -> SimOptions:
        if self.log.format in ("ulog", "mavros") and self.px4.interface != "px4":
            raise ValueError(
                f"log.format {self.log.format} records a PX4 vehicle: set px4.interface: px4 "
                "(the log's attitude setpoints are the PX4 interface's)"
            )
        return self
