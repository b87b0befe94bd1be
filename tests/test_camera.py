"""The camera loop (issue 25): rendered frames, IMU and the MSCKF on known trajectories.

Trajectories are replayed through :func:`qsls.pipeline.sim.camera.loop.replay` (the true
motion is known in closed form), and flown in the closed loop through ``qsls simulate``.
"""

from __future__ import annotations

import numpy as np
import pytest

from qsls.pipeline.evaluate.rpe import rpe_windows
from qsls.pipeline.sim.camera.loop import replay
from qsls.pipeline.sim.camera.options import CameraOptions
from tests.reference_impl import thrust_attitudes


def figure_eight(seconds: float, half_width: float = 1.0, period: float = 10.0, hz: float = 200.0):
    """``p(t) = (A sin wt, A/2 sin 2wt, 1 + 0.1 sin wt)`` and the attitude that flies it."""
    t = np.arange(round(seconds * hz) + 1) / hz
    w = 2 * np.pi / period
    a = half_width
    p = np.stack([a * np.sin(w * t), 0.5 * a * np.sin(2 * w * t), 1.0 + 0.1 * np.sin(w * t)], 1)
    acc = np.stack(
        [
            -a * w * w * np.sin(w * t),
            -2 * a * w * w * np.sin(2 * w * t),
            -0.1 * w * w * np.sin(w * t),
        ],
        1,
    )
    return t, p, thrust_attitudes(acc)


def circle(seconds: float, radius: float, period: float, hz: float = 200.0):
    t = np.arange(round(seconds * hz) + 1) / hz
    w = 2 * np.pi / period
    p = np.stack([radius * np.cos(w * t), radius * np.sin(w * t), np.full_like(t, 1.0)], 1)
    acc = np.stack([-radius * w * w * np.cos(w * t), -radius * w * w * np.sin(w * t), 0 * t], 1)
    return t, p, thrust_attitudes(acc)


def test_noise_free_figure_eight_within_2cm():
    """Exact IMU, noise-free sharp images of full texture: within 2 cm over 20 s."""
    t, p, q = figure_eight(20.0)
    cam = CameraOptions(noise=False, imu_noise=False)
    est, _, loop = replay(cam, 1.0, 1.0, 0, t, p, q)
    err = np.linalg.norm(est[:, :3] - p, axis=1)
    assert err.max() < 0.02, err.max()
    v = np.gradient(p, t, axis=0)
    assert np.linalg.norm(est[:, 3:] - v, axis=1).max() < 0.05
    info = loop.describe()
    assert info["features_per_frame"] > 30 and info["features_used"] > 500


def test_lens_cap_runs_on_imu_and_recovers():
    """Black frames for 3 s: no update, the covariance grows, no NaN; after the cap comes
    off the features return and the covariance shrinks again."""
    t, p, q = figure_eight(14.0)
    cam = CameraOptions(lens_cap=[(5.0, 8.0)])
    est, _, loop = replay(cam, 1.0, 1.0, 0, t, p, q, record=True)
    ts, sig = np.array(loop.nees)[:, [0, 3]].T
    assert np.isfinite(est).all()
    before = sig[(ts > 4.0) & (ts < 5.0)].max()
    capped = sig[(ts > 7.5) & (ts < 8.0)].min()
    after = sig[(ts > 12.0)].max()
    assert capped > 3 * before, (before, capped)
    assert after < 0.5 * capped, (capped, after)
    err = np.linalg.norm(est[:, :3] - p, axis=1)
    assert err[t > 10.0].max() < 0.3


def test_consistency_nees_in_band():
    """Noise-only run (IMU and image noise, regular light): the NEES of [p, v] (6 dof) lies
    within its two-sided chi-square 99% band on most frames, and its mean is not above
    the 6 a consistent filter has (a pessimistic filter is allowed; an overconfident one not)."""
    from scipy.stats import chi2

    t, p, q = figure_eight(20.0)
    _, _, loop = replay(CameraOptions(), 1.0, 1.0, 3, t, p, q, record=True)
    nees = np.array(loop.nees)[1:, 1]
    lo, hi = chi2.ppf([0.005, 0.995], 6)
    inside = np.mean((nees > lo) & (nees < hi))
    assert inside > 0.8, inside
    assert np.mean(nees > hi) < 0.05
    assert nees.mean() < 12.0


def test_consistency_degraded_nees_in_band():
    """The same check in the degraded condition (light 0.35, texture 0.45: longer exposure,
    more blur and noise, weaker corners), seed 8 (the noise model was calibrated on seeds
    3, 5, 7): with the pixel noise from the image formation (docs/camera.md) the NEES is
    within its band on most frames and its mean not above 6 by much; with the fixed 0.3 px
    the filter is overconfident (measured before: mean 9-19 over seeds 3-7)."""
    from scipy.stats import chi2

    t, p, q = figure_eight(20.0)
    lo, hi = chi2.ppf([0.005, 0.995], 6)
    means = {}
    for model in ("image", "fixed"):
        cam = CameraOptions(pixel_noise=model)
        _, _, loop = replay(cam, 0.35, 0.45, 8, t, p, q, record=True)
        nees = np.array(loop.nees)[1:, 1]
        means[model] = nees.mean()
        if model == "image":
            assert np.mean((nees > lo) & (nees < hi)) > 0.8
            assert np.mean(nees > hi) < 0.05
            assert nees.mean() < 9.0, nees.mean()
            assert loop.resets == []
    assert means["fixed"] > 1.3 * means["image"], means


def test_same_seed_same_bits_other_seed_other_bits():
    t, p, q = figure_eight(3.0)
    a = replay(CameraOptions(), 1.0, 1.0, 5, t, p, q)
    b = replay(CameraOptions(), 1.0, 1.0, 5, t, p, q)
    c = replay(CameraOptions(), 1.0, 1.0, 6, t, p, q)
    assert a[2].describe()["frames_sha256"] == b[2].describe()["frames_sha256"]
    assert a[0].tobytes() == b[0].tobytes() and a[1].tobytes() == b[1].tobytes()
    assert a[2].describe()["frames_sha256"] != c[2].describe()["frames_sha256"]
    assert a[0].tobytes() != c[0].tobytes()


def _rpe(t, p, est) -> float:
    _, _, rpe = rpe_windows(t, p, est[:, :3], 1.0)
    return float(rpe.mean())


@pytest.mark.slow
def test_faster_flight_and_less_light_larger_rpe():
    """Paired by seed: the 1 s RPE grows when the same circle is flown 2.7 times as fast
    (0.8 to 2.1 m/s: more blur, features cross the image sooner), when the slow circle is
    flown in little light (0.15: the exposure capped at 6 ms, 340 instead of 1500 electrons,
    so more blur and twice the noise), and in the degraded condition (light 0.35, texture
    0.45). Measured (seeds 0-2): fast 1.2-1.3x, light 0.15 1.2-1.6x. The degraded light alone
    (0.35 at full texture) raised it with the fixed 0.3 px noise model; with the noise taken
    from the image the filter weighs the noisier features less, and at 0.8 m/s its effect
    (0.8-1.1x) is within the seeds' scatter, so it is not asserted."""
    slow = circle(12.0, 1.0, 8.0)
    fast = circle(12.0, 1.0, 3.0)
    cam = CameraOptions()
    for seed in (0, 1, 2):
        r_slow = _rpe(slow[0], slow[1], replay(cam, 1.0, 1.0, seed, *slow)[0])
        r_fast = _rpe(fast[0], fast[1], replay(cam, 1.0, 1.0, seed, *fast)[0])
        r_dark = _rpe(slow[0], slow[1], replay(cam, 0.15, 1.0, seed, *slow)[0])
        r_degr = _rpe(slow[0], slow[1], replay(cam, 0.35, 0.45, seed, *slow)[0])
        assert r_fast > r_slow, (seed, r_slow, r_fast)
        assert r_dark > r_slow, (seed, r_slow, r_dark)
        assert r_degr > r_slow, (seed, r_slow, r_degr)


@pytest.mark.slow
def test_weaker_texture_and_more_blur_larger_rpe():
    """Paired by seed: the 1 s RPE grows on a floor of weak texture (strength 0.15: fewer,
    weaker corners, each localized worse), and with motion blur alone (a circle flown at 2.5
    m/s under a 45 ms exposure instead of 4 ms, at the same photon count per pixel, so the
    noise does not change: 33 px of blur on average instead of 3).

    Measured (issue 50), seeds 0-5, with OpenCV 5.1 and 4.14 (the two render different bits,
    so different realizations): texture 2.4-4.0x and 2.0-4.0x (0.007-0.012 -> 0.021-0.030 m),
    blur 2.2-3.1x and 2.2-3.6x (0.010-0.015 -> 0.027-0.041 m); asserted at 1.6x. The contrasts
    the test had before were within the seeds' scatter once the pixel noise came from the
    image (which weighs weak and blurred features less): texture 0.3 measured 0.47-1.56x
    (OpenCV 5.1, seeds 0-5) and 0.66-1.28x (4.10-4.14, seeds 0-2), blur at 30 ms on a 2.1 m/s
    circle (18 px) 1.03-1.64x (5.1, seeds 0-5), so which seed passed depended on the
    rendering's last bits."""
    mid = circle(12.0, 1.0, 5.0)
    fast = circle(12.0, 1.0, 2.5)
    cam = CameraOptions()
    blurred = CameraOptions(exposure_s=0.045, exposure_max_s=0.045, blur_max_substeps=32)
    for seed in (0, 1):  # each seed's ratio measured 2.0x or more (docstring): two suffice
        r_mid = _rpe(mid[0], mid[1], replay(cam, 1.0, 1.0, seed, *mid)[0])
        r_weak = _rpe(mid[0], mid[1], replay(cam, 1.0, 0.15, seed, *mid)[0])
        r_fast = _rpe(fast[0], fast[1], replay(cam, 1.0, 1.0, seed, *fast)[0])
        r_blur = _rpe(fast[0], fast[1], replay(blurred, 1.0, 1.0, seed, *fast)[0])
        assert r_weak > 1.6 * r_mid, (seed, r_mid, r_weak)
        assert r_blur > 1.6 * r_fast, (seed, r_fast, r_blur)


def test_camera_facing_away_is_refused():
    from qsls.pipeline.core.errors import ConfigError

    t, p, q = figure_eight(1.0)
    with pytest.raises(ConfigError, match="textured plane on 0% of its image"):
        replay(CameraOptions(pitch_deg=180.0), 1.0, 1.0, 0, t, p, q)


def test_camera_over_budget_is_refused():
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match="speed budget"):
        CameraOptions(width=752, height=480, rate_hz=20.0)


def _fly_with_kick(cam: CameraOptions, kick_t: float, kick_v: float, seconds: float = 14.0):
    """Replay the figure eight and, at ``kick_t``, knock the filter's velocity off by
    ``kick_v`` (m/s) with its covariance untouched: an overconfident, wrong filter."""
    from qsls.pipeline.sim.camera.loop import CameraVio, trajectory_states

    t, p, q = figure_eight(seconds)
    s, h_ns = trajectory_states(t, p, q)
    loop = CameraVio(cam, 1.0, 1.0, 2, 9.81, h_ns)
    loop.start(s[0])
    est = np.zeros((len(t), 6))
    est[0] = loop.estimate()[0]
    for i in range(len(t) - 1):
        if i == round(kick_t * 200):
            loop.filter.v = loop.filter.v + np.array([kick_v, 0.0, 0.0])
        loop.step(s[i], s[i + 1])
        est[i + 1] = loop.estimate()[0]
    return t, np.linalg.norm(est[:, :3] - p, axis=1), loop


def test_diverged_filter_is_detected_and_reinitialized():
    """A wrong velocity the covariance does not admit: the camera's features fail the gate
    (innovation check), the filter restarts (velocity and tilt re-initialized, position
    kept) and the error stops growing; with the reset off it grows without bound."""
    t, err, loop = _fly_with_kick(CameraOptions(), 5.0, 0.5)
    _, err_off, off = _fly_with_kick(CameraOptions(reset=False), 5.0, 0.5)
    assert off.resets == [] and loop.describe()["resets"] == len(loop.resets) >= 1
    t_reset, why = loop.resets[0]
    assert 5.0 < t_reset < 6.5 and why.startswith("innovations"), loop.resets
    assert np.isfinite(err).all()
    kept = err[np.searchsorted(t, t_reset)]
    assert err[t > t_reset + 1.0].max() < kept + 0.1, (kept, err.max())
    assert err_off[-1] > 3 * err[-1] and err_off[-1] > 1.0, (err_off[-1], err[-1])
    assert (err[t < 5.0] == err_off[t < 5.0]).all()  # the same flight until the kick


def test_lost_filter_reinitializes_when_the_scene_returns():
    """A lens cap long enough for the position std to pass ``reset_sigma_position``: the
    filter is lost, waits in the dark (no features to initialize on), and restarts at the
    first well-conditioned window (measurements only); no NaN; its covariance shrinks back."""
    t, p, q = figure_eight(14.0)
    cam = CameraOptions(lens_cap=[(4.0, 9.0)], reset_sigma_position=0.15)
    est, _, loop = replay(cam, 1.0, 1.0, 0, t, p, q, record=True)
    assert np.isfinite(est).all()
    assert len(loop.resets) == 1, loop.resets
    t_reset, why = loop.resets[0]
    # the closed-form re-initialization waits for enough frames with tracks after the cap
    # (measured: refused until 9.65 s, the velocity std too large; then errors 0.04 m/s, 0.2 deg)
    assert 9.0 <= t_reset < 10.0 and why.startswith("covariance"), loop.resets
    ts, nees, sig = np.array(loop.nees)[:, [0, 1, 3]].T
    assert sig[(ts > 8.8) & (ts < 9.0)].min() > 0.15
    # the position (and yaw) are carried over from the lost estimate with its uncertainty:
    # the camera cannot observe them, so the std stays at what the dark seconds left (measured
    # 0.044-0.09 m), never the 1 mm prior of a filter that starts at the truth ...
    after = ts > t_reset
    assert sig[after].min() > 0.03 and sig[after].max() < 0.12
    # ... and the new filter is consistent: NEES of [p, v] inside chi2(6)'s 99 % bound
    # (16.8) after the reset (measured: median 2.5-3.4, max 6.8; with the 1 mm prior the
    # carried 5 cm position error read 28 sigma)
    assert np.mean(nees[after] < 16.81) > 0.95


def test_fast_on_free_cells_finds_the_whole_images_corners():
    """The tracker runs FAST on each free grid cell grown by a halo; the corners (and their
    scores) it keeps are exactly those FAST finds on the whole image inside those cells."""
    import cv2

    from qsls.pipeline.sim.camera.loop import CameraVio, trajectory_states
    from qsls.pipeline.sim.camera.tracker import _MARGIN, Tracker

    cam = CameraOptions()
    t, p, q = figure_eight(1.0)
    s, h_ns = trajectory_states(t, p, q)
    loop = CameraVio(cam, 0.35, 0.45, 1, 9.81, h_ns)
    img = loop.renderer.render(
        np.eye(3), s[100, 0:3], s[100, 10:13], s[100, 3:6], loop.r_bc, loop.t_bc
    )
    tr = Tracker(cam)
    rng = np.random.default_rng(0)
    whole = cv2.FastFeatureDetector.create(cam.fast_threshold, True).detect(img)
    wxy = np.array([k.pt for k in whole], np.float32)
    wresp = np.array([k.response for k in whole], np.float32)
    inside = (
        (wxy[:, 0] >= _MARGIN) & (wxy[:, 0] <= cam.width - 1 - _MARGIN)
        & (wxy[:, 1] >= _MARGIN) & (wxy[:, 1] <= cam.height - 1 - _MARGIN)
    )  # fmt: skip
    for _ in range(5):
        taken = rng.random(tr.cols * tr.rows) < 0.6
        xy, resp = tr._corners(img, taken)
        keep = inside & ~taken[tr._cells(wxy)]
        want = sorted(zip(map(tuple, wxy[keep].tolist()), wresp[keep].tolist(), strict=True))
        got = sorted(zip(map(tuple, xy.tolist()), resp.tolist(), strict=True))
        assert len(got) > 20 and got == want
