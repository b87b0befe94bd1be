"""The camera loop's estimator-only re-initialization (pipeline/sim/camera/vinit.py,
estimator.py): the closed-form visual-inertial initialization on synthetic windows, and the
estimator's independence from the truth."""

from __future__ import annotations

import inspect
from typing import ClassVar

import numpy as np

from qsls.pipeline.core.rotations import quat_to_matrix
from qsls.pipeline.sim.camera.estimator import Estimator
from qsls.pipeline.sim.camera.geometry import camera_in_body
from qsls.pipeline.sim.camera.imu import true_rates
from qsls.pipeline.sim.camera.loop import CameraVio, trajectory_states
from qsls.pipeline.sim.camera.options import CameraOptions
from qsls.pipeline.sim.camera.vinit import InitRefusal, InitSolution, closed_form_init
from tests.test_camera import figure_eight

G = 9.81


def _window(t0: float, noise_px: float, seed: int = 0, hover: bool = False):
    """One second of exact IMU samples and projections of 300 random floor points (70 kept
    per frame) seen at 20 Hz from the figure eight (or hovering at its start), with pixel
    noise; and the true gravity and velocity in the window's first body frame."""
    t, p, q = figure_eight(t0 + 1.1)
    if hover:
        p, q = np.repeat(p[:1], len(t), 0), np.repeat(q[:1], len(t), 0)
    s, h_ns = trajectory_states(t, p, q)
    h = h_ns / 1e9
    k0, k1 = round(t0 * 200), round(t0 * 200) + 200
    r = quat_to_matrix(s[:, 6:10])
    rates = [true_rates(r[i], r[i + 1], s[i, 3:6], s[i + 1, 3:6], h, G) for i in range(k0, k1)]
    wm, am = np.array([w for w, _ in rates]), np.array([a for _, a in rates])
    r_bc, t_bc = camera_in_body(30.0), np.array([0.05, 0.0, -0.02])
    rng = np.random.default_rng(seed)
    pts = np.c_[rng.uniform(-1.5, 2.5, (300, 2)), np.zeros(300)]
    frames = np.arange(0, 201, 10)
    of, oi, ouv = [], [], []
    for j, kk in enumerate(frames):
        i = k0 + kk
        r_wc, p_c = r[i] @ r_bc, s[i, :3] + r[i] @ t_bc
        x = (pts - p_c) @ r_wc
        uv = x[:, :2] / x[:, 2:3]
        ok = (x[:, 2] > 0.1) & (np.abs(uv[:, 0]) < 188 / 229) & (np.abs(uv[:, 1]) < 120 / 229)
        idx = np.flatnonzero(ok)[:70]
        of.append(np.full(len(idx), j))
        oi.append(idx)
        ouv.append(uv[idx] + noise_px / 229 * rng.standard_normal((len(idx), 2)))
    n = sum(map(len, oi))
    sol = closed_form_init(
        wm, am, np.full(len(wm), h), frames, np.concatenate(of), np.concatenate(oi),
        np.concatenate(ouv), np.full(n, max(noise_px, 0.1) / 229), r_bc, t_bc, G,
    )  # fmt: skip
    return sol, r[k0].T @ np.array([0.0, 0.0, -G]), r[k0].T @ s[k1, 3:6]


def test_closed_form_init_exact_and_noisy():
    """Exact measurements: gravity and velocity to 1e-4; 0.3 px of noise: the errors lie
    within 3 of the solution's reported standard deviations (white noise, as assumed)."""
    sol, g_true, v_true = _window(3.0, 0.0)
    assert isinstance(sol, InitSolution), sol
    assert np.linalg.norm(sol.g0 - g_true) < 1e-4
    assert np.linalg.norm(sol.v_m - v_true) < 1e-4
    for seed in (0, 1, 2):
        sol, g_true, v_true = _window(3.0, 0.3, seed)
        assert isinstance(sol, InitSolution), sol
        assert 0.8 < sol.residual_rms < 1.2
        e = sol.v_m - v_true
        assert e @ np.linalg.solve(sol.cov_v, e) < 14.2, (e, sol.cov_v)  # chi2(3) 99.7%
        tilt = np.arccos(np.clip(sol.g0 @ g_true / G**2, -1, 1))
        assert tilt < 3 * sol.sigma_tilt + 1e-9, (np.degrees(tilt), np.degrees(sol.sigma_tilt))


def test_closed_form_init_refuses_a_window_without_motion():
    """Hovering still: no parallax, the features' distances (and with them the velocity's
    link to the images) are unobservable; the window is refused, not solved badly."""
    sol, _, _ = _window(3.0, 0.3, hover=True)
    assert isinstance(sol, InitRefusal), sol


def test_estimator_takes_measurements_only():
    """Structurally: after the start, the estimator's inputs are the IMU samples and the
    tracked features (no state, no truth)."""
    params = {
        name: list(inspect.signature(getattr(Estimator, name)).parameters)[1:]
        for name in ("propagate", "frame", "solve_window")
    }
    assert params == {
        "propagate": ["wm", "am", "h"],
        "frame": ["t", "ids", "uv", "sigma"],
        "solve_window": [],
    }


class _Recording(Estimator):
    """The estimator, keeping every measurement it is given."""

    stream: ClassVar[list[tuple]] = []

    def propagate(self, wm, am, h):
        self.stream.append(("imu", wm.copy(), am.copy(), h))
        super().propagate(wm, am, h)

    def frame(self, t, ids, uv, sigma):
        self.stream.append(("frame", t, ids.copy(), uv.copy(), sigma.copy()))
        super().frame(t, ids, uv, sigma)


def test_reinitialized_estimates_depend_on_the_measurements_only(monkeypatch):
    """A flight that loses the filter (5 s lens cap, covariance check) and re-initializes:
    its measurement stream replayed into a fresh estimator, given only the start state,
    gives the same estimates bit for bit and the same reset, and the re-initialization
    recovers the velocity within 0.1 m/s and the tilt within 1 degree of the truth."""
    from qsls.pipeline.sim.camera import loop as camera_loop

    monkeypatch.setattr(camera_loop, "Estimator", _Recording)
    monkeypatch.setattr(_Recording, "stream", [])
    cam = CameraOptions(lens_cap=[(4.0, 9.0)], reset_sigma_position=0.15)
    t, p, q = figure_eight(12.0)
    s, h_ns = trajectory_states(t, p, q)
    loop = CameraVio(cam, 1.0, 1.0, 0, G, h_ns)
    loop.start(s[0])
    est = loop.estimator
    assert isinstance(est, _Recording)
    out = [np.r_[est.filter.p, est.filter.v, est.filter.R.ravel()]]
    for i in range(len(t) - 1):
        loop.step(s[i], s[i + 1])
        out.append(np.r_[est.filter.p, est.filter.v, est.filter.R.ravel()])
    assert len(loop.resets) == 1 and loop.resets[0][1].startswith("covariance")
    ((_, dv, dtilt),) = loop.reset_errors
    assert dv < 0.1 and dtilt < 1.0, (dv, dtilt)
    # the same stream, a fresh estimator given the start state only
    stream = _Recording.stream
    r0 = quat_to_matrix(s[0, 6:10])
    fresh = Estimator(cam, loop.r_bc, loop.t_bc, G, r0, s[0, 0:3], s[0, 3:6])
    again = []
    for k, item in enumerate(stream):
        if item[0] == "imu":
            fresh.propagate(*item[1:])
        else:
            fresh.frame(*item[1:])
        if k + 1 == len(stream) or stream[k + 1][0] == "imu":  # after a step and its frame
            again.append(np.r_[fresh.filter.p, fresh.filter.v, fresh.filter.R.ravel()])
    assert fresh.resets == loop.resets
    assert np.array_equal(np.array(again), np.array(out))
