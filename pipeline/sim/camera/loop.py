"""The camera VIO in the loop: IMU, rendered frames, tracker and MSCKF, step by step.

:class:`CameraVio` is driven by the closed loop once per physics step with the vehicle's
true states at both ends of the step (``s = [p, v, q xyzw, omega_body, ...]``): the step
makes one IMU sample (:mod:`.imu`) that propagates the filter; a step ending on a frame time
(every ``1 / rate_hz``) renders the frame from the true pose at that time (:mod:`.render`),
tracks features (:mod:`.tracker`), takes each feature's noise from the image (:mod:`.noise`)
and hands the features to the estimator (:mod:`.estimator`: the MSCKF of :mod:`.msckf`, its
health checks and re-initialization), which is given the true state once, at the start, and
only measurements after. The estimate (position, velocity, attitude) is the filter's state
after the latest step. Nothing here uses the emulator's error model.

Random streams (``SeedSequence(seed)`` children, distinct from the emulator's): IMU noise,
image noise. The world's texture has its own seed (``camera.texture_seed``).

:func:`replay` runs the same on a recorded trajectory (EuRoC ground truth) instead of a
closed loop.
"""

from __future__ import annotations

import hashlib
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from qsls.pipeline.core.errors import ConfigError
from qsls.pipeline.core.rotations import quat_to_matrix
from qsls.pipeline.core.units import NS
from qsls.pipeline.sim.camera.estimator import Estimator
from qsls.pipeline.sim.camera.geometry import camera_in_body, matrix_quat, so3_log
from qsls.pipeline.sim.camera.imu import Imu, true_rates
from qsls.pipeline.sim.camera.msckf import Msckf
from qsls.pipeline.sim.camera.noise import pixel_sigma
from qsls.pipeline.sim.camera.options import CameraOptions
from qsls.pipeline.sim.camera.render import Renderer
from qsls.pipeline.sim.camera.tracker import Tracker
from qsls.pipeline.sim.camera.world import build_world

_STREAM_IMU, _STREAM_IMAGE = 101, 102
MIN_VISIBLE = 0.3
"""Least fraction of the image on a textured plane at the start pose (else refused)."""


@dataclass
class Snapshot:
    """One frame kept for the report: the image and its tracked features (pixels)."""

    t_s: float
    image: np.ndarray
    points: np.ndarray

    def arrays(self) -> dict[str, np.ndarray]:
        """As arrays (``camera_frame.npz``): ``t_s`` (), ``image`` (h, w) uint8, ``points``
        (n, 2) float32 pixels."""
        return {"t_s": np.asarray(self.t_s), "image": self.image, "points": self.points}


class CameraVio:
    """The camera loop of the module docstring."""

    def __init__(
        self, cam: CameraOptions, light: float, texture: float, seed: int,
        gravity: float, h_ns: int, *, snapshot_s: float | None = None,
    ) -> None:  # fmt: skip
        self.cam = cam
        self.light, self.texture = float(light), float(texture)
        self.gravity = float(gravity)
        self.h_ns = int(h_ns)
        frame_ns = NS / cam.rate_hz
        self.steps_per_frame = round(frame_ns / h_ns)
        if self.steps_per_frame < 1 or abs(frame_ns / h_ns - self.steps_per_frame) > 1e-6:
            raise ConfigError(
                f"camera rate {cam.rate_hz:g} Hz is not a whole number of physics steps "
                f"({h_ns / NS:g} s); choose vio.camera.rate_hz dividing vehicle.physics_hz"
            )
        self.r_bc = camera_in_body(cam.pitch_deg)
        self.t_bc = np.asarray(cam.offset_m, dtype=float)
        root = np.random.SeedSequence(int(seed))
        self.imu = Imu(cam, h_ns / NS, np.random.SeedSequence([int(seed), _STREAM_IMU]))
        del root
        self.renderer = Renderer(
            cam, build_world(cam, self.texture), self.light,
            np.random.SeedSequence([int(seed), _STREAM_IMAGE]),
        )  # fmt: skip
        self.tracker = Tracker(cam)
        self.estimator: Estimator | None = None
        self.reset_errors: list[tuple[float, float, float]] = []
        """Per re-initialization (evaluation only, never seen by the estimator): (time s,
        velocity error m/s, tilt error deg) of the new estimate against the truth."""
        self.step_index = 0
        self.frames = 0
        self.features_sum = 0
        self.blur_sum = 0.0
        self.dark = [(float(a), float(b)) for a, b in cam.lens_cap]
        self._digest = hashlib.sha256()
        self.snapshot_s = cam.snapshot_s if snapshot_s is None else snapshot_s
        self.snapshot: Snapshot | None = None
        self.nees: list[tuple[float, float, float, float]] = []
        """Per frame when ``record_nees``: (t, NEES of [p, v], NEES of the attitude, the
        position's standard deviation ``sqrt(trace P_pp)``)."""
        self.record_nees = False
        self.seconds = {"imu": 0.0, "render": 0.0, "track": 0.0, "filter": 0.0}
        """CPU seconds of this process spent per part (for benchmarks/bench_camera.py; the
        CPU clock, not the wall clock, so that other processes on the machine do not count)."""

    # ------------------------------------------------------------------ checks
    def check_view(self, s0: np.ndarray, what: str = "the start pose") -> float:
        """Refuse a camera that sees no textured plane from ``s0`` (one line)."""
        r_wb = quat_to_matrix(s0[6:10])
        frac = self.renderer.visible_fraction(r_wb @ self.r_bc, s0[0:3] + r_wb @ self.t_bc)
        if frac < MIN_VISIBLE:
            raise ConfigError(
                f"the camera (pitch {self.cam.pitch_deg:g} deg from straight down) sees a "
                f"textured plane on {100 * frac:.0f}% of its image from {what} "
                f"(position {', '.join(f'{v:.2f}' for v in s0[0:3])} m; at least "
                f"{100 * MIN_VISIBLE:.0f}% needed): point it at the ground or add walls"
            )
        return frac

    # ------------------------------------------------------------------ running
    @property
    def filter(self) -> Msckf | None:
        """The estimator's current MSCKF."""
        return None if self.estimator is None else self.estimator.filter

    @property
    def resets(self) -> list[tuple[float, str]]:
        """Re-initializations: (time s, why) (:class:`.estimator.Estimator`)."""
        return [] if self.estimator is None else self.estimator.resets

    def start(self, s0: np.ndarray) -> None:
        """Start the estimator at the true start state (a VIO initialized at rest: the
        estimate's world frame is the start pose); after this the estimator sees only the
        IMU samples and the tracked features."""
        self.estimator = Estimator(
            self.cam, self.r_bc, self.t_bc, self.gravity,
            quat_to_matrix(s0[6:10]), s0[0:3].astype(float), s0[3:6].astype(float),
        )  # fmt: skip
        self.step_index = 0
        self._s_last: np.ndarray | None = None
        self._r_last = np.eye(3)
        self._frame(s0, 0.0)

    def step(self, s0: np.ndarray, s1: np.ndarray) -> None:
        """One physics step from true state ``s0`` to ``s1`` (module docstring)."""
        est = self.estimator
        assert est is not None
        h = self.h_ns / NS
        c0 = time.process_time()
        r0 = self._r_last if self._s_last is s0 else quat_to_matrix(s0[6:10])
        r1 = quat_to_matrix(s1[6:10])
        self._s_last, self._r_last = s1, r1
        omega, acc = true_rates(r0, r1, s0[3:6], s1[3:6], h, self.gravity)
        wm, am = self.imu.measure(omega, acc)
        c1 = time.process_time()
        est.propagate(wm, am, h)
        self.seconds["imu"] += c1 - c0
        self.seconds["filter"] += time.process_time() - c1
        self.step_index += 1
        if self.step_index % self.steps_per_frame == 0:
            self._frame(s1, self.step_index * h, r1)

    def _frame(self, s: np.ndarray, t: float, r_wb: np.ndarray | None = None) -> None:
        est = self.estimator
        assert est is not None
        r_wb = quat_to_matrix(s[6:10]) if r_wb is None else r_wb
        dark = any(a <= t < b for a, b in self.dark)
        c0 = time.process_time()
        img = self.renderer.render(r_wb, s[0:3], s[10:13], s[3:6], self.r_bc, self.t_bc, dark=dark)
        c1 = time.process_time()
        self._digest.update(img.tobytes())
        ids, pts = self.tracker.track(img)
        if self.cam.pixel_noise == "image":
            sig_px = pixel_sigma(self.cam, img, pts, self.renderer.electrons)
        else:
            sig_px = np.full(len(ids), self.cam.pixel_sigma)
        c2 = time.process_time()
        k = self.renderer.k
        uv = (pts.astype(float) - k[:2, 2]) / self.cam.focal_px
        n_resets = len(est.resets)
        est.frame(t, ids, uv, sig_px / self.cam.focal_px)
        if len(est.resets) > n_resets:
            self.reset_errors.append((t, *self._errors(s, r_wb)))
        c3 = time.process_time()
        self.seconds["render"] += c1 - c0
        self.seconds["track"] += c2 - c1
        self.seconds["filter"] += c3 - c2
        self.frames += 1
        self.features_sum += len(ids)
        self.blur_sum += self.renderer.last_blur_px
        if self.snapshot_s is not None and self.snapshot is None and t >= self.snapshot_s:
            self.snapshot = Snapshot(t_s=t, image=img, points=pts)
        if self.record_nees:
            self.nees.append((t, *self.nees_now(s, r_wb)))

    def _errors(self, s: np.ndarray, r_wb: np.ndarray) -> tuple[float, float]:
        """Velocity error (m/s) and tilt error (deg: the angle between the estimated and the
        true gravity direction in the body frame) of the estimate against the truth ``s``."""
        flt = self.filter
        assert flt is not None
        dv = float(np.linalg.norm(flt.v - s[3:6]))
        cos = float(np.clip(flt.R[2] @ r_wb[2], -1.0, 1.0))
        return dv, math.degrees(math.acos(cos))

    def nees_now(self, s: np.ndarray, r_wb: np.ndarray) -> tuple[float, float, float]:
        """Normalized estimation error squared of ``[p, v]`` (6 dof) and of the attitude
        (3 dof) against the true state ``s``: ``e^T P^-1 e``; and ``sqrt(trace P_pp)``."""
        flt = self.filter
        assert flt is not None
        p = flt.imu_covariance()
        e = np.concatenate([s[0:3] - flt.p, s[3:6] - flt.v])
        dth = so3_log(r_wb @ flt.R.T)
        pv = p[3:9, 3:9]
        return (
            float(e @ np.linalg.solve(pv, e)),
            float(dth @ np.linalg.solve(p[0:3, 0:3], dth)),
            float(np.sqrt(np.trace(p[3:6, 3:6]))),
        )

    def estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """``([p, v] (6,), q xyzw (4,))``: the filter's latest estimate."""
        flt = self.filter
        assert flt is not None
        return np.concatenate([flt.p, flt.v]), matrix_quat(flt.R)

    def describe(self) -> dict[str, Any]:
        """What the camera loop did (for ``truth.json``)."""
        flt = self.filter
        n = max(self.frames, 1)
        return {
            "estimator": "msckf",
            "light": self.light,
            "texture_level": self.texture,
            "exposure_s": self.renderer.t_exp,
            "electrons_white": self.renderer.electrons,
            "frames": self.frames,
            "features_per_frame": self.features_sum / n,
            "blur_px_mean": self.blur_sum / n,
            "features_used": flt.used_features if flt else 0,
            "features_gated": flt.gated_features if flt else 0,
            "ransac_rejected": self.tracker.rejected,
            "resets": len(self.resets),
            "reset_times_s": [round(t, 3) for t, _ in self.resets],
            "reset_refusals": len(self.estimator.init_refusals) if self.estimator else 0,
            "reset_velocity_error": [round(e, 4) for _, e, _ in self.reset_errors],
            "reset_tilt_error_deg": [round(e, 4) for _, _, e in self.reset_errors],
            "frames_sha256": self._digest.hexdigest(),
        }


def replay(
    cam: CameraOptions,
    light: float,
    texture: float,
    seed: int,
    t: np.ndarray,
    p: np.ndarray,
    q: np.ndarray,
    *,
    gravity: float = 9.81,
    record: bool = False,
) -> tuple[np.ndarray, np.ndarray, CameraVio]:
    """Fly a recorded trajectory through the camera loop (no controller).

    ``t`` (n,) uniformly spaced times (s), ``p`` (n, 3) positions, ``q`` (n, 4) attitudes
    (xyzw, body to world). Velocities are central differences of ``p``, body rates the
    relative rotation between samples. ``record``: keep the NEES per frame
    (:attr:`CameraVio.nees`). Returns the estimated ``[p, v]`` (n, 6) and attitudes
    (n, 4) at the samples, and the loop (its counters).
    """
    s, h_ns = trajectory_states(t, p, q)
    n = len(t)
    loop = CameraVio(cam, light, texture, seed, gravity, h_ns)
    loop.record_nees = record
    loop.check_view(s[0])
    loop.start(s[0])
    est = np.zeros((n, 6))
    att = np.zeros((n, 4))
    est[0], att[0] = loop.estimate()
    for i in range(n - 1):
        loop.step(s[i], s[i + 1])
        est[i + 1], att[i + 1] = loop.estimate()
    return est, att, loop


def trajectory_states(t: np.ndarray, p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, int]:
    """The loop's true states ``[p, v, q, omega_body]`` (n, 13) of a recorded trajectory
    (:func:`replay`'s arguments) and its step (ns): velocities are central differences of
    ``p``, body rates the relative rotation between samples."""
    h = float(np.median(np.diff(t)))
    v = np.gradient(p, t, axis=0)
    n = len(t)
    s = np.zeros((n, 13))
    s[:, 0:3], s[:, 3:6], s[:, 6:10] = p, v, q
    rs = quat_to_matrix(q)
    for i in range(n - 1):
        s[i, 10:13] = so3_log(rs[i].T @ rs[i + 1]) / h
    s[-1, 10:13] = s[-2, 10:13]
    return s, round(h * NS)
