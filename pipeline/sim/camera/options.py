"""Options of the camera loop: camera, image formation, world, IMU, tracker and filter.

Defaults: EuRoC's cam0 (752x480, f = 458 px, 20 Hz) at half resolution (376x240, f = 229
px), looking down and ``pitch_deg`` = 30 degrees forward; EuRoC's ADIS16448 noise densities
(``sensors/imu0/sensor.yaml`` of the dataset: gyroscope 1.6968e-4 rad/s/sqrt(Hz), random walk
1.9393e-5 rad/s^2/sqrt(Hz); accelerometer 2.0e-3 m/s^2/sqrt(Hz), random walk 3.0e-3
m/s^3/sqrt(Hz)) at 200 Hz.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from qsls.pipeline.core.config import Options

# Budget (issue 25): a 30 s flight in <= 3 s on one core. Measured costs (benchmarks/
# bench_camera.py) put the pixel work at about 2.4 ms per frame at 376x240 and 20 Hz; a
# camera whose pixel rate exceeds this bound cannot be simulated in budget.
MAX_PIXEL_RATE = 376 * 240 * 30.0
"""Largest width * height * rate_hz (pixels per second of flight) accepted."""


class Wall(Options):
    """A vertical textured wall: the segment from ``start`` to ``end`` (x, y in m), from
    ``bottom`` to ``top`` (z in m)."""

    start: tuple[float, float] = (-4.0, 4.0)
    end: tuple[float, float] = (4.0, 4.0)
    bottom: float = 0.0
    top: float = Field(3.0, gt=0)

    @model_validator(mode="after")
    def _extent(self) -> Wall:
        if self.top <= self.bottom:
            raise ValueError(f"wall top {self.top} must be above its bottom {self.bottom}")
        if self.start == self.end:
            raise ValueError("wall start and end must differ")
        return self


class TexturePath(Options):
    """Where the ground's texture is rich: near the reference path (docs/camera.md,
    "State-dependent perception"). The contrast is full within ``band_m`` of the horizontal
    circle of ``radius`` about ``centre`` or within ``pad_m`` of the centre (the take-off and
    approach), and falls linearly over ``ramp_m`` to ``level`` of it farther away, so a
    vehicle that strays from the path sees a poorer floor."""

    radius: float = Field(1.0, gt=0)
    centre: tuple[float, float] = (0.0, 0.0)
    band_m: float = Field(0.3, ge=0)
    ramp_m: float = Field(0.3, gt=0)
    pad_m: float = Field(0.3, ge=0)
    level: float = Field(0.2, ge=0, le=1)
    """Contrast far from the path, relative to the path's."""


DEGRADED_LIGHT = 0.15
DEGRADED_TEXTURE = 0.25
"""The camera's degraded perception on the default (uniform) floor: fewer photons and weaker
texture together, the mildest level that at least doubled the estimator's error on every
seed measured (SE3, 30 s, seeds 0 to 5: 2.69 to 10.3 times regular, geometric mean 4.13;
the shared 0.35 / 0.45 gave 0.49 to 2.60, 1.24: docs/camera.md)."""


class CameraOptions(Options):
    """The camera loop's parameters (``vio.camera`` in a config)."""

    # ---------------------------------------------------------------- camera
    width: int = Field(376, ge=32, le=1280)
    height: int = Field(240, ge=32, le=1024)
    focal_px: float = Field(229.0, gt=0)
    """Focal length (px) of the undistorted pinhole; the principal point is the centre."""
    rate_hz: float = Field(20.0, gt=0, le=60)
    """Frame rate; frames fall on physics steps (a whole number of them per frame)."""
    pitch_deg: float = Field(30.0, ge=-180, le=180)
    """Optical axis tilted this far from straight down towards the body's +x (forward): 0
    looks down, 90 forward, 180 up."""
    offset_m: tuple[float, float, float] = (0.05, 0.0, -0.02)
    """Camera centre in the body frame (m)."""

    # ---------------------------------------------------------------- image formation
    exposure_s: float = Field(0.004, gt=0)
    """Exposure in full light (s); auto exposure lengthens it as ``exposure_s / light``."""
    exposure_max_s: float = Field(0.006, gt=0)
    """Longest exposure (s); below that light the gain rises instead (more noise)."""
    full_well_e: float = Field(1500.0, gt=0)
    """Electrons collected by a white pixel in full light at ``exposure_s``."""
    read_noise_e: float = Field(6.0, ge=0)
    """Read noise (electrons RMS)."""
    noise: bool = True
    """Shot and read noise; off: the noise-free (still quantized, clipped) image."""
    snapshot_s: float | None = Field(10.0, ge=0)
    """Flight time (s) of the one frame kept with its tracked features (``qsls simulate``
    writes it as ``camera_frame.npz``, the report shows it); None keeps none."""
    lens_cap: list[tuple[float, float]] = Field(default_factory=list)
    """Intervals ``[start, end)`` (s from the flight's start) with the lens covered: black
    frames (read noise only), so the filter runs on the IMU alone."""
    blur_px_per_substep: float = Field(1.5, gt=0)
    """Image motion (px) per sub-frame render averaged over the exposure (at least one)."""
    blur_max_substeps: int = Field(6, ge=1, le=32)
    """Most sub-frame renders of one frame."""

    degraded_light: float | None = Field(DEGRADED_LIGHT, gt=0, le=1)
    """The camera's own degraded light level: 0.15 degrades the camera loop on the default
    floor (docs/camera.md, "A degraded condition that degrades"); None takes
    ``vio.degraded.light``, the emulator's 0.35, which barely does.
    ``configs/paper_sim_camera.yaml`` sets its calibrated 0.2."""
    degraded_texture: float | None = Field(DEGRADED_TEXTURE, gt=0, le=1)
    """The camera's own degraded texture level: 0.25 (None: ``vio.degraded.texture``, 0.45);
    ``configs/paper_sim_camera.yaml`` sets 0.3 (with ``degraded_light`` 0.2)."""

    # ---------------------------------------------------------------- world
    texture_seed: int = Field(7, ge=0)
    """Seed of the procedural textures (the world, not the flight's noise)."""
    texture_m_per_px: float = Field(0.005, gt=0)
    """Texture resolution on the planes (m per texel)."""
    texture_size_m: float = Field(8.0, gt=0)
    """Side of one texture tile (m); the ground repeats it."""
    texture_strength: float = Field(1.0, ge=0, le=1)
    """Contrast of the texture at regular perception, times the perception level's texture."""
    ground_z: float = 0.0
    """Height of the ground plane (m)."""
    walls: list[Wall] = Field(default_factory=list)
    """Optional vertical walls (none by default: the paper's camera looks at the floor)."""
    texture_path: TexturePath | None = None
    """Poor texture away from the reference path (None: the floor is alike everywhere)."""

    # ---------------------------------------------------------------- IMU
    imu_noise: bool = True
    """White noise and bias random walks; off: the IMU measures the exact motion."""
    gyro_noise: float = Field(1.6968e-4, ge=0)
    """Gyroscope white noise density (rad/s/sqrt(Hz))."""
    gyro_walk: float = Field(1.9393e-5, ge=0)
    """Gyroscope bias random walk (rad/s^2/sqrt(Hz))."""
    accel_noise: float = Field(2.0e-3, ge=0)
    """Accelerometer white noise density (m/s^2/sqrt(Hz))."""
    accel_walk: float = Field(3.0e-3, ge=0)
    """Accelerometer bias random walk (m/s^3/sqrt(Hz))."""
    gyro_bias0: float = Field(0.0, ge=0)
    """Std of the initial gyroscope bias (rad/s), unknown to the filter beyond its prior."""
    accel_bias0: float = Field(0.0, ge=0)
    """Std of the initial accelerometer bias (m/s^2)."""

    # ---------------------------------------------------------------- tracker
    max_features: int = Field(70, ge=8, le=400)
    """Features tracked at once; new ones (FAST, strongest per grid cell) fill the gaps."""
    fast_threshold: int = Field(12, ge=1, le=100)
    grid: tuple[int, int] = (6, 4)
    """Detection grid (columns, rows): at most one new feature per free cell per frame."""
    klt_window: int = Field(15, ge=5, le=41)
    klt_levels: int = Field(2, ge=0, le=5)
    ransac_px: float = Field(1.0, gt=0)
    """RANSAC threshold of the fundamental-matrix outlier rejection (px)."""

    # ---------------------------------------------------------------- filter
    window: int = Field(10, ge=3, le=30)
    """Camera clones in the sliding window."""
    pixel_noise: Literal["image", "fixed"] = "image"
    """Feature measurement noise the filter assumes: ``image``, per feature and frame from the
    image formation (:mod:`.noise`: the structure tensor around the feature and the camera's
    gain); ``fixed``, ``pixel_sigma`` for every feature."""
    pixel_sigma: float = Field(0.3, gt=0)
    """Feature measurement noise (px) of the ``fixed`` model."""
    pixel_sigma_floor: float = Field(0.1, gt=0)
    """``image`` model: the floor ``sigma_0`` (px)."""
    pixel_noise_scale: float = Field(2.0, gt=0)
    """``image`` model: ``k``, the factor on the Cramer-Rao bound of the KLT alignment."""
    pixel_sigma_max: float = Field(3.0, gt=0)
    """``image`` model: the largest std assumed (px)."""
    min_track: int = Field(3, ge=2)
    """Observations a feature needs before it constrains the clones."""
    min_parallax_ratio: float = Field(0.02, gt=0)
    """Triangulation needs baseline / depth above this."""
    chi2_gate: float = Field(0.95, gt=0, lt=1)
    """Per-feature Mahalanobis gate (chi-square quantile)."""
    init_sigma_position: float = Field(0.001, gt=0)
    init_sigma_velocity: float = Field(0.01, gt=0)
    init_sigma_tilt_deg: float = Field(0.5, gt=0)
    init_sigma_yaw_deg: float = Field(0.1, gt=0)
    init_sigma_gyro_bias: float = Field(1e-3, gt=0)
    init_sigma_accel_bias: float = Field(2e-2, gt=0)

    # ---------------------------------------------------------------- failure and reset
    reset: bool = True
    """Detect a diverged or lost filter and re-initialize it (docs/camera.md); off: the
    filter runs on whatever it has, however wrong (for comparison)."""
    reset_window_s: float = Field(1.0, gt=0)
    """Span of the innovation check (s of frames)."""
    reset_min_gated: int = Field(10, ge=1)
    """Innovation check: at least this many features rejected by the chi-square gate over the
    span, and ..."""
    reset_gated_fraction: float = Field(0.8, gt=0, le=1)
    """... at least this fraction of the features that reached the gate: the filter's
    predictions disagree with what the camera sees (diverged)."""
    reset_sigma_position: float = Field(2.0, gt=0)
    """Covariance check: ``sqrt(trace P_pp)`` above this (m) means the estimate is lost (too
    long on the IMU alone: no parallax, no features)."""
    reset_min_features: int = Field(20, ge=1)
    """Re-initialization waits until the tracker holds this many features (as a real VIO's
    initialization needs a tracked scene)."""
    init_window_s: float = Field(1.0, gt=0)
    """Re-initialization (:mod:`.vinit`): the window of frames and IMU samples it solves."""
    init_min_features: int = Field(20, ge=3)
    """... at least this many features seen in 3 frames of the window, ..."""
    init_max_sigma_velocity: float = Field(0.2, gt=0)
    """... the velocity's std (m/s) at most this, ..."""
    init_max_sigma_tilt_deg: float = Field(2.0, gt=0)
    """... the tilt's std (deg) at most this, ..."""
    init_max_residual: float = Field(3.0, gt=0)
    """... and the whitened residuals' RMS at most this; else it retries at the next frame."""
    init_sigma_scale: float = Field(2.5, gt=0)
    """Factor on the solution's standard deviations (its least squares takes the tracks'
    errors as independent; measured on the figure eight, its errors are about 4 times the
    independent-error std)."""

    @model_validator(mode="after")
    def _budget(self) -> CameraOptions:
        rate = self.width * self.height * self.rate_hz
        if rate > MAX_PIXEL_RATE:
            raise ValueError(
                f"camera {self.width}x{self.height} at {self.rate_hz:g} Hz is "
                f"{rate / 1e6:.2f} Mpx per second of flight, more than the "
                f"{MAX_PIXEL_RATE / 1e6:.2f} Mpx/s that fit the speed budget "
                "(a 30 s flight in 3 s); lower width, height or rate_hz"
            )
        if self.exposure_max_s < self.exposure_s:
            raise ValueError("exposure_max_s must be >= exposure_s")
        if self.exposure_max_s >= 1.0 / self.rate_hz:
            raise ValueError(
                f"exposure_max_s {self.exposure_max_s:g} s must be shorter than a frame "
                f"({1.0 / self.rate_hz:g} s)"
            )
        return self
