"""The VIO emulator's motion-dependent parts: blur, drift with motion, feature loss, and the
closed-loop mechanism (a rougher-flown vehicle sees a worse estimate)."""

from __future__ import annotations

import numpy as np
import pytest

from qsls.pipeline.sim.closedloop import FlightOptions, fly
from qsls.pipeline.sim.vio import VioEmulator, VioParams

STATIC_OFF = {"bias": False, "drift": False, "noise": False, "outliers": False}
MOTION_OFF = {"blur": False, "motion_drift": False, "feature_loss": False}
ALL_ON = {"blur": True, "motion_drift": True, "feature_loss": True}


def only(part: str, **kw) -> VioParams:
    return VioParams.model_validate({**STATIC_OFF, **MOTION_OFF, part: True, **kw})


def hover(n: int, v=(0.0, 0.0, 0.0), z: float = 2.0) -> np.ndarray:
    x = np.zeros((n, 6))
    x[:, 2], x[:, 3:] = z, v
    return x


def test_blur_pixels_by_hand_and_longer_exposure_in_poor_light():
    x = hover(1, v=(0.6, 0.8, 0.0), z=2.0)
    w = np.array([[0.0, 0.0, 2.0]])
    # b = t_exp f (|omega| + |v_xy| / max(z, 0.3)) = 0.005 * 460 * (2 + 1 / 2) = 5.75 px
    assert VioEmulator(only("blur"), 0).blur(x, w)[0] == pytest.approx(5.75, rel=1e-12)
    deg = VioEmulator(only("blur", perception="degraded"), 0)
    assert deg.exposure_s == pytest.approx(0.005 / 0.35)
    assert deg.blur(x, w)[0] == pytest.approx(5.75 / 0.35, rel=1e-12)
    # low flight: the translation term stops growing at blur_min_height
    low = hover(1, v=(0.3, 0.0, 0.0), z=0.1)
    assert VioEmulator(only("blur"), 0).blur(low, np.zeros((1, 3)))[0] == pytest.approx(
        0.005 * 460 * 1.0
    )


def test_blur_noise_and_outliers_grow_with_the_blur():
    n = 40_000
    prm = only("blur", blur_outlier_rate=0.004)
    still = VioEmulator(prm, 1).errors(hover(n), np.zeros((n, 3)))
    assert not still.any()  # no motion, no blur: nothing
    w = np.tile([0.0, 0.0, 3.0], (n, 1))
    e = VioEmulator(prm, 1).errors(hover(n), w)
    b = 0.005 * 460 * 3.0  # 6.9 px
    np.testing.assert_allclose(e[:, :3].std(axis=0), b * prm.blur_noise_position, rtol=0.03)
    spikes = np.abs(e[:, 3:]) > prm.outlier_min
    rate = spikes.any(axis=1).mean()
    assert rate == pytest.approx(prm.blur_outlier_rate * b, rel=0.15)
    clean = ~spikes.any(axis=1)
    np.testing.assert_allclose(e[clean, 3:].std(axis=0), b * prm.blur_noise_velocity, rtol=0.05)


def test_drift_per_radian_and_faster_per_metre_when_fast():
    n, rate = 500, 1.2
    em = VioEmulator(only("motion_drift", drift_walk_radian=0.0, drift_walk=0.0), 2)
    e = em.errors(hover(n), np.tile([rate, 0.0, 0.0], (n, 1)))
    turned = rate * (n - 1) / 100.0  # the first sample has turned through nothing
    np.testing.assert_allclose(e[-1, :3], 0.002 * turned * em.drift_direction, rtol=1e-9)
    assert not e[:, 3:].any()
    # along a line at speed s with both drift sums on: drift_fraction (1 + gain s) per metre
    prm = VioParams.model_validate(
        {**STATIC_OFF, **MOTION_OFF, "drift": True, "motion_drift": True,
         "drift_walk": 0.0, "drift_walk_radian": 0.0}
    )  # fmt: skip
    for s in (0.5, 2.0):
        t = np.arange(n) / 100.0
        x = hover(n, v=(s, 0.0, 0.0))
        x[:, 0] = s * t
        em = VioEmulator(prm, 2)
        e = em.errors(x)
        dist = s * t[-1]
        per_m = prm.drift_fraction * (1 + prm.drift_speed_gain * s)
        np.testing.assert_allclose(e[-1, :3], per_m * dist * em.drift_direction, rtol=1e-9)


def test_feature_loss_only_above_thresholds_and_more_often_in_poor_texture():
    n = 60_000
    calm = np.tile([0.0, 0.0, 2.5], (n, 1))  # below 3 rad/s
    assert not VioEmulator(only("feature_loss"), 3).errors(hover(n), calm).any()
    jerk = np.tile([0.0, 0.0, 9.0], (n, 1))  # acceleration above 8 m/s^2
    fast = np.tile([0.0, 0.0, 3.5], (n, 1))
    odds = {}
    for perception in ("regular", "degraded"):
        prm = only("feature_loss", perception=perception)
        em = VioEmulator(prm, 3)
        e = em.errors(hover(n), fast)
        assert np.array_equal(e, VioEmulator(prm, 3).errors(hover(n), calm, jerk))
        lost = np.abs(e).max(axis=1) > 0
        frac = lost.mean()
        assert np.abs(e[:, :3]).max() <= prm.loss_position
        assert np.abs(e[:, 3:]).max() <= prm.loss_velocity
        # expected share of samples in a burst: renewal of (wait ~ geometric, burst ~ 40 samples)
        q = em.light * em.texture(hover(1))[0]
        p = -np.expm1(-prm.loss_rate_hz * (1 + prm.loss_texture_gain * (1 - q)) / 100.0)
        mean_len = (20 + 60) / 2
        assert frac == pytest.approx(mean_len / (mean_len + 1 / p), rel=0.15)
        odds[perception] = frac / (1 - frac)  # = p * mean_len: the start rate's share
    # burst rate 0.5 (1 + 4 (1 - q)): q = 0.62 (regular) and 0.10 (degraded), ratio 1.84
    assert odds["degraded"] > 1.5 * odds["regular"]


def test_sample_equals_errors_with_motion_parts_and_bursts_across_calls():
    rng = np.random.default_rng(4)
    n = 3000
    t = np.arange(n) / 100.0
    x = np.c_[np.cos(t), np.sin(t), 1 + 0 * t, -np.sin(t), np.cos(t), 0 * t]
    w = rng.normal(0, 1.5, (n, 3))
    a = rng.normal(0, 3, (n, 3))
    prm = VioParams(**ALL_ON, perception="degraded")
    whole = VioEmulator(prm, 9).errors(x, w, a)
    em = VioEmulator(prm, 9)
    stepped = np.array([em.sample(x[k], w[k], a[k]) for k in range(n)])
    assert np.array_equal(whole, stepped)
    em.reset()
    chunks = np.vstack([em.errors(x[i : i + 137], w[i : i + 137], a[i : i + 137])
                        for i in range(0, n, 137)])  # fmt: skip
    assert np.array_equal(whole, chunks)
    # the motion parts are noise-like: the bias field and its Lipschitz constant are unchanged
    off = VioEmulator(VioParams(**MOTION_OFF, perception="degraded"), 9)
    assert em.lipschitz == off.lipschitz
    assert np.array_equal(em.bias(x), off.bias(x))


def _pd_flight(scale: float, motion: dict[str, bool]) -> FlightOptions:
    return FlightOptions.model_validate(
        {
            "duration": 12.0,
            "controller": {
                "kind": "pd",
                "pd": {
                    "kp": [2 * scale, 2 * scale, 4 * scale],
                    "kd": [2.2 * scale, 2.2 * scale, 3 * scale],
                },
            },
            "vio": {"perception": "degraded", **motion},
        }
    )


@pytest.mark.slow
def test_pd_flown_harder_sees_more_blur_and_a_worse_estimate():
    """Same reference, same seed: PD at 2x its gains turns faster than at 0.5x, so in degraded
    perception the blur (and with it the perception error) grows; without the motion parts
    the two estimates are about as good (the error depended on position only)."""
    for seed in (0, 1):
        soft, hard = (fly(_pd_flight(k, ALL_ON), seed=seed) for k in (0.5, 2.0))
        assert not soft.crashed and not hard.crashed
        rate = [np.linalg.norm(f.vio_w, axis=1).mean() for f in (soft, hard)]
        assert rate[1] > 2.0 * rate[0]
        rms = [f.metrics()["perception_error_rms"] for f in (soft, hard)]
        assert rms[1] > 1.03 * rms[0], rms  # measured 5 to 10 % on seeds 0-3
        blur_only = {**MOTION_OFF, "blur": True}
        rms_blur = [fly(_pd_flight(k, blur_only), seed=seed).metrics()["perception_error_rms"]
                    for k in (0.5, 2.0)]  # fmt: skip
        assert rms_blur[1] > 1.03 * rms_blur[0], rms_blur
        rms_off = [fly(_pd_flight(k, MOTION_OFF), seed=seed).metrics()["perception_error_rms"]
                   for k in (0.5, 2.0)]  # fmt: skip
        assert abs(rms_off[1] / rms_off[0] - 1) < 0.01, rms_off
