"""The estimator side of the camera loop: the MSCKF, its health checks and its
re-initialization, fed with measurements only.

:class:`Estimator` receives IMU samples (:meth:`Estimator.propagate`) and, per frame, the
tracked features' normalized image points and their noise std (:meth:`Estimator.frame`). It
never sees the vehicle's true state after the start: the re-initialization after a failure
(:meth:`.msckf.Msckf.health`) solves velocity and tilt from the last ``init_window_s`` of
IMU samples and tracked features in closed form (:mod:`.vinit`), and keeps position and yaw
from the lost estimate (no initialization observes them). When the window is ill-conditioned
(too few features, too little motion, residuals too large) it waits and tries again at the
next frame while the lost filter keeps running.

The start (``r0, p0, v0``) is the one state it is given: the world frame of the estimate is
anchored at the vehicle's start pose (a VIO initialized at rest, as docs/camera.md says).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from qsls.pipeline.sim.camera.geometry import so3_exp
from qsls.pipeline.sim.camera.msckf import Msckf
from qsls.pipeline.sim.camera.options import CameraOptions
from qsls.pipeline.sim.camera.vinit import (
    InitRefusal,
    InitSolution,
    closed_form_init,
    world_from_first,
)


@dataclass(frozen=True)
class _FrameRecord:
    """One frame for the re-initialization window: the IMU samples since the previous
    frame, and the features seen (ids, normalized points, noise std)."""

    wm: np.ndarray
    am: np.ndarray
    h: np.ndarray
    ids: np.ndarray
    uv: np.ndarray
    sigma: np.ndarray


def yaw_of(r: np.ndarray) -> float:
    """Heading of the body's x axis: ``atan2(R_10, R_00)``."""
    return math.atan2(float(r[1, 0]), float(r[0, 0]))


class Estimator:
    """The MSCKF with failure detection and measurement-only re-initialization (module
    docstring)."""

    def __init__(
        self, cam: CameraOptions, r_bc: np.ndarray, t_bc: np.ndarray, gravity: float,
        r0: np.ndarray, p0: np.ndarray, v0: np.ndarray,
    ) -> None:  # fmt: skip
        self.cam = cam
        self.r_bc, self.t_bc, self.gravity = r_bc, t_bc, float(gravity)
        self.filter = Msckf(cam, r_bc, t_bc, gravity, r0, p0, v0)
        self.resets: list[tuple[float, str]] = []
        """Re-initializations: (time s, why the filter was declared lost)."""
        self.lost: str | None = None
        """Why the filter was declared lost, while it waits for a well-conditioned window."""
        self.init_refusals: list[tuple[float, str]] = []
        """Windows refused while lost: (time s, why)."""
        self.frame_count = 0
        self._wm: list[np.ndarray] = []
        self._am: list[np.ndarray] = []
        self._h: list[float] = []
        self._window: deque[_FrameRecord] = deque(
            maxlen=max(3, round(cam.init_window_s * cam.rate_hz) + 1)
        )

    def propagate(self, wm: np.ndarray, am: np.ndarray, h: float) -> None:
        """One IMU sample (rates in the body frame, step ``h`` s)."""
        self.filter.propagate(wm, am, h)
        if self.cam.reset:
            self._wm.append(wm)
            self._am.append(am)
            self._h.append(h)

    def frame(self, t: float, ids: np.ndarray, uv: np.ndarray, sigma: np.ndarray) -> None:
        """One frame at time ``t`` (s): features ``ids`` (n,) at normalized points ``uv``
        (n, 2) with noise std ``sigma`` (n,) (normalized); then the health check and, when
        lost, a re-initialization attempt (module docstring)."""
        flt = self.filter
        flt.process_frame(self.frame_count, ids, uv, sigma)
        self.frame_count += 1
        cam = self.cam
        if not cam.reset:
            return
        k = len(self._h)
        self._window.append(
            _FrameRecord(
                np.array(self._wm).reshape(k, 3), np.array(self._am).reshape(k, 3),
                np.array(self._h), ids.copy(), uv.copy(), sigma.copy(),
            )
        )  # fmt: skip
        self._wm, self._am, self._h = [], [], []
        if len(ids) < cam.reset_min_features:
            return
        if self.lost is None:
            self.lost = flt.health()
        if self.lost is not None:
            self._try_reinitialize(t)

    def solve_window(self) -> InitSolution | InitRefusal:
        """The closed-form initialization (:func:`.vinit.closed_form_init`) of the last
        ``init_window_s`` of IMU samples and tracked features."""
        cam = self.cam
        frames = list(self._window)
        if len(frames) < 3:
            return InitRefusal(f"{len(frames)} frames in the window")
        wm = np.concatenate([f.wm for f in frames[1:]])
        am = np.concatenate([f.am for f in frames[1:]])
        h = np.concatenate([f.h for f in frames[1:]])
        frame_sample = np.concatenate([[0], np.cumsum([len(f.h) for f in frames[1:]])])
        return closed_form_init(
            wm, am, h, frame_sample,
            np.concatenate([np.full(len(f.ids), j) for j, f in enumerate(frames)]),
            np.concatenate([f.ids for f in frames]),
            np.concatenate([f.uv for f in frames]),
            np.concatenate([f.sigma for f in frames]),
            self.r_bc, self.t_bc, self.gravity,
            min_features=cam.init_min_features,
            max_sigma_velocity=cam.init_max_sigma_velocity,
            max_sigma_tilt=math.radians(cam.init_max_sigma_tilt_deg),
            max_residual=cam.init_max_residual,
            sigma_scale=cam.init_sigma_scale,
        )  # fmt: skip

    def _try_reinitialize(self, t: float) -> None:
        """Solve the window (:meth:`solve_window`); on success replace the filter by a fresh
        one: attitude and velocity from the solution, its yaw and position those of the lost
        estimate, zero biases; covariance the initial prior, with the tilt and velocity
        blocks at least the solution's and the position and yaw blocks the lost estimate's
        (they are carried over, and the camera cannot observe them: a prior of 1 mm would
        claim a certainty the carried estimate does not have; docs/camera.md)."""
        cam = self.cam
        sol = self.solve_window()
        if isinstance(sol, InitRefusal):
            self.init_refusals.append((t, sol.why))
            return
        old = self.filter
        r_w0 = world_from_first(sol.g0)
        r_now = r_w0 @ sol.r_0m
        rz = so3_exp(np.array([0.0, 0.0, yaw_of(old.R) - yaw_of(r_now)]))
        r_w0 = rz @ r_w0
        new = Msckf(cam, self.r_bc, self.t_bc, self.gravity, rz @ r_now, old.p.copy(),
                    r_w0 @ sol.v_m)  # fmt: skip
        p0 = new.P
        tilt2 = max(math.radians(cam.init_sigma_tilt_deg) ** 2, sol.sigma_tilt**2)
        p0[0, 0] = p0[1, 1] = tilt2
        p0[6:9, 6:9] = r_w0 @ sol.cov_v @ r_w0.T + cam.init_sigma_velocity**2 * np.eye(3)
        p_old = old.imu_covariance()
        p0[3:6, 3:6] = p_old[3:6, 3:6]
        p0[2, 2] = max(p0[2, 2], float(p_old[2, 2]))
        new.position_var0 = float(np.trace(p0[3:6, 3:6]))
        new.used_features, new.gated_features = old.used_features, old.gated_features
        self.filter = new
        self.resets.append((t, self.lost or ""))
        self.lost = None
