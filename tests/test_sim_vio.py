"""The VIO emulator: closed-form Lipschitz constant, steep parts on the circle, switches."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from qsls.pipeline.core.config import validate
from qsls.pipeline.core.errors import ConfigError
from qsls.pipeline.sim.vio import VioEmulator, VioParams, scaled_ridges

MOTION_OFF = {"blur": False, "motion_drift": False, "feature_loss": False}
BIAS_ONLY = {"drift": False, "noise": False, "outliers": False, **MOTION_OFF}


def circle_states(dt: float, seconds: float = 15.0, radius: float = 1.0, hz: float = 0.2):
    t = np.arange(0.0, seconds, dt)
    w = 2 * np.pi * hz
    return np.c_[
        radius * np.cos(w * t),
        radius * np.sin(w * t),
        np.ones_like(t),
        -radius * w * np.sin(w * t),
        radius * w * np.cos(w * t),
        np.zeros_like(t),
    ]


def max_pair_slope(x: np.ndarray, e: np.ndarray, r: float) -> float:
    pairs = cKDTree(x).query_pairs(r, p=np.inf, output_type="ndarray")
    dx = np.abs(x[pairs[:, 0]] - x[pairs[:, 1]]).max(axis=1)
    de = np.abs(e[pairs[:, 0]] - e[pairs[:, 1]]).max(axis=1)
    keep = dx > 1e-12
    return float((de[keep] / dx[keep]).max())


@pytest.mark.parametrize("perception", ["regular", "degraded"])
def test_lipschitz_bounds_random_pairs_and_is_nearly_attained_on_circle(perception):
    em = VioEmulator(VioParams(perception=perception), seed=0)
    lip = em.lipschitz
    assert lip > 0
    rng = np.random.default_rng(1)
    x = rng.uniform(-2, 2, (50_000, 6))
    for scale in (1e-4, 1e-2, 0.5):
        d = rng.normal(0, scale, x.shape)
        slope = np.abs(em.bias(x + d) - em.bias(x)).max(1) / np.abs(d).max(1)
        assert slope.max() <= lip * (1 + 1e-9)
    # the default circle crosses the steep parts: a slope estimator sees >= 0.5 L
    for dt in (0.01, 0.1):
        xc = circle_states(dt)
        assert max_pair_slope(xc, em.bias(xc), r=0.5) >= 0.5 * lip


def test_degraded_raises_bias_noise_and_outliers():
    reg = VioEmulator(VioParams(), seed=0)
    deg = VioEmulator(VioParams(perception="degraded"), seed=0)
    x = circle_states(0.01)
    assert deg.lipschitz > reg.lipschitz
    assert np.all(deg.noise_std(x) > reg.noise_std(x))
    assert deg.outlier_prob > reg.outlier_prob
    # noise is larger over the low-texture patch than away from it
    s = reg.noise_std(np.array([[-0.6, 0.6], [0.375, 0.0]]))
    assert s[0, 0] > 2.5 * s[1, 0]


def test_sample_equals_errors_and_seed_determinism():
    x = circle_states(0.01, seconds=10)
    a = VioEmulator(VioParams(), seed=7).errors(x)
    em = VioEmulator(VioParams(), seed=7)
    b = np.array([em.sample(xi) for xi in x])
    assert np.array_equal(a, b)
    em.reset()
    assert np.array_equal(em.errors(x[:300]), a[:300])
    c = VioEmulator(VioParams(), seed=8).errors(x)
    assert not np.array_equal(a, c)


def test_switches_isolate_parts():
    x = circle_states(0.01, seconds=30)
    bias_only = VioEmulator(VioParams(**BIAS_ONLY), seed=3)
    assert np.array_equal(bias_only.errors(x), bias_only.bias(x))
    nothing = VioEmulator(VioParams(bias=False, **BIAS_ONLY), seed=3)
    assert nothing.lipschitz == 0.0
    assert not nothing.errors(x).any()
    # drift only: grows with distance travelled (~ drift_fraction * distance), position only
    prm = VioParams(bias=False, noise=False, outliers=False, drift_walk=0.0, **MOTION_OFF)
    em = VioEmulator(prm, seed=3)
    e = em.errors(x)
    assert not e[:, 3:].any()
    dist = em.distance
    assert dist == pytest.approx(2 * np.pi * 1.0 * 0.2 * 30, rel=0.01)
    assert np.linalg.norm(e[-1, :3]) == pytest.approx(prm.drift_fraction * dist, rel=1e-6)
    # outliers only: velocity spikes within [min, max], rare
    prm = VioParams(bias=False, drift=False, noise=False, outlier_prob=0.05, **MOTION_OFF)
    o = VioEmulator(prm, seed=3).errors(x)
    assert not o[:, :3].any()
    mags = np.abs(o[:, 3:][o[:, 3:] != 0])
    assert 0.01 * len(x) < len(mags) < 0.1 * len(x)
    assert mags.min() >= prm.outlier_min and mags.max() <= prm.outlier_max
    # switching noise off leaves the other parts' values unchanged
    full = VioEmulator(VioParams(), seed=3).errors(x)
    no_noise = VioEmulator(VioParams(noise=False), seed=3).errors(x)
    z = (full - no_noise) / VioEmulator(VioParams(), seed=3).noise_std(x)
    assert np.abs(z).max() < 6 and 0.8 < z.std() < 1.2


@pytest.mark.parametrize(
    "bad",
    [
        {"rate_hz": 10},
        {"noise_position": -1},
        {"outlier_min": 2.0, "outlier_max": 1.0},
        {"bias_typo": 1},
    ],
)
def test_bad_params(bad):
    with pytest.raises(ConfigError):
        validate(VioParams, bad)


# The last commit before the motion-dependent parts (blur, drift with motion, feature loss).
BEFORE_MOTION = "7b7af2e"


def _emulator_before_motion(tmp_path, monkeypatch):
    """The VioEmulator class of ``BEFORE_MOTION``'s vio.py, loaded from git."""
    import importlib.util
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    got = subprocess.run(
        ["git", "show", f"{BEFORE_MOTION}:pipeline/sim/vio.py"],
        cwd=root, capture_output=True, text=True, check=False,
    )  # fmt: skip
    if got.returncode != 0:
        pytest.skip(f"git history with {BEFORE_MOTION} not available: {got.stderr.strip()}")
    path = tmp_path / "vio_before_motion.py"
    path.write_text(got.stdout)
    spec = importlib.util.spec_from_file_location("vio_before_motion", path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, mod)  # pydantic resolves annotations there
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize(
    "extra", [{}, {"perception": "degraded"}, {"outlier_prob": 0.05, "drift_walk": 0.01}]
)
def test_motion_parts_off_is_bit_identical_to_the_emulator_before_them(
    tmp_path, monkeypatch, extra
):
    old = _emulator_before_motion(tmp_path, monkeypatch)
    x = circle_states(0.01, seconds=20)
    rng = np.random.default_rng(5)
    omega, accel = rng.normal(0, 3, (len(x), 3)), rng.normal(0, 6, (len(x), 3))
    # the same bias field: the default ridges were recalibrated after (FIRST_RIDGES)
    ridges = [r.model_dump() for r in old.VioParams().ridges]
    assert ridges == [r.model_dump() for r in scaled_ridges(1.0, 1.0)]
    for seed in (0, 11):
        want = old.VioEmulator(old.VioParams(**extra), seed).errors(x)
        new = VioEmulator(VioParams(**MOTION_OFF, ridges=ridges, **extra), seed)
        got = new.errors(x, omega, accel)
        assert got.tobytes() == want.tobytes()
        new.reset()
        stepped = np.array([new.sample(x[k], omega[k], accel[k]) for k in range(300)])
        assert stepped.tobytes() == want[:300].tobytes()


def test_the_mapped_region_error_grows_with_the_distance_outside_it_and_l_bounds_it():
    """``vio.region`` (issue 47: the emulator's error did not depend on where the vehicle was,
    so range flights could not measure S): zero inside the region, ``slope`` metres per metre
    outward beyond it, and the emulator's Lipschitz constant still bounds the whole field."""
    from qsls.pipeline.sim.options import VioParams
    from qsls.pipeline.sim.vio import VioEmulator

    params = VioParams.model_validate(
        {"region": {"center": [0.5, 0.0], "radius": 1.0, "slope": 0.1}}
    )
    emu = VioEmulator(params, seed=0)
    base = VioEmulator(VioParams(), seed=0)
    p = np.array([[0.5, 0.0], [1.2, 0.0], [2.5, 0.0], [0.5, -3.0]])
    np.testing.assert_allclose(
        emu.region_error(p), [[0, 0], [0, 0], [0.1, 0], [0, -0.2]], atol=1e-15
    )
    x = np.hstack([p, np.ones((4, 1)), np.zeros((4, 3))])
    np.testing.assert_allclose(
        emu.bias(x) - base.bias(x), np.hstack([emu.region_error(p), np.zeros((4, 4))])
    )
    assert emu.lipschitz >= base.lipschitz
    rng = np.random.default_rng(1)
    a, b = rng.uniform(-4, 4, (2000, 6)), rng.uniform(-4, 4, (2000, 6))
    ratio = np.abs(emu.bias(a) - emu.bias(b)).max(axis=1) / np.abs(a - b).max(axis=1)
    assert ratio.max() <= emu.lipschitz + 1e-12
