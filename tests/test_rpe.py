"""The RPE-versus-speed statistic on synthetic flights whose answer is known in closed form."""

from __future__ import annotations

import numpy as np
import pytest

from qsls.pipeline.evaluate.rpe import RpeSpeed, rpe_windows, speed_statistic


def rpe_vs_speed(t: np.ndarray, p: np.ndarray, q: np.ndarray, window: float = 1.0) -> RpeSpeed:
    """:func:`speed_statistic` of :func:`rpe_windows`."""
    _, speed, rpe = rpe_windows(t, p, q, window)
    return speed_statistic(speed, rpe)


DT = 0.1


def _flight(speeds: np.ndarray, err_step: np.ndarray, seed: int = 0):
    """Truth straight within each 1 s window at ``speeds[j]`` (heading changing per window),
    estimate ``q = p + e`` whose error moves by ``err_step[j]`` (m) over window ``j`` in a
    random direction, on top of a constant offset (which RPE must cancel)."""
    rng = np.random.default_rng(seed)
    n_win = len(speeds)
    per = round(1.0 / DT)
    t = np.arange(n_win * per + 1) * DT
    heading = rng.uniform(0, 2 * np.pi, n_win)
    vel = np.c_[np.cos(heading), np.sin(heading), np.zeros(n_win)] * speeds[:, None]
    edir = rng.normal(size=(n_win, 3))
    edir /= np.linalg.norm(edir, axis=1, keepdims=True)
    erate = edir * err_step[:, None]
    v = np.repeat(vel, per, axis=0)
    de = np.repeat(erate, per, axis=0)
    p0, e0 = np.array([0.3, -0.2, 1.0]), np.array([0.05, 0.02, -0.1])
    p = p0 + np.vstack([np.zeros(3), np.cumsum(v * DT, axis=0)])
    e = e0 + np.vstack([np.zeros(3), np.cumsum(de * DT, axis=0)])
    return t, p, p + e


def test_rpe_proportional_to_speed_gives_the_speed_ratio_and_rho_one():
    rng = np.random.default_rng(1)
    speeds = rng.permutation(np.linspace(0.2, 1.4, 30))
    c = 0.04  # RPE = c * speed (m per m travelled)
    t, p, q = _flight(speeds, c * speeds)
    t0, sp, rpe = rpe_windows(t, p, q)
    assert len(t0) == 30
    np.testing.assert_allclose(sp, speeds, rtol=1e-9)
    np.testing.assert_allclose(rpe, c * speeds, rtol=1e-9)
    st = rpe_vs_speed(t, p, q)
    s = np.sort(speeds)
    assert st.ratio == pytest.approx(s[-10:].mean() / s[:10].mean(), rel=1e-9)
    assert st.rho == pytest.approx(1.0)
    assert st.windows == 30


def test_rpe_falling_with_speed_gives_negative_rho_and_ratio_below_one():
    speeds = np.random.default_rng(2).permutation(np.linspace(0.3, 1.5, 12))
    t, p, q = _flight(speeds, 0.02 / speeds)
    st = rpe_vs_speed(t, p, q)
    s = np.sort(speeds)
    assert st.ratio == pytest.approx((1 / s[-4:]).mean() / (1 / s[:4]).mean(), rel=1e-9)
    assert st.rho == pytest.approx(-1.0)


def test_a_gap_drops_its_windows_instead_of_stretching_them():
    speeds = np.linspace(0.2, 1.0, 10)
    t, p, q = _flight(speeds, 0.05 * speeds)
    cut = (t > 3.05) & (t < 3.95)  # window [3, 4] loses its interior, ends still there
    gap = (t > 4.05) & (t < 5.05)  # window [4, 5] loses its end sample at t = 5
    keep = ~gap
    t0, sp, rpe = rpe_windows(t[keep & ~cut], p[keep & ~cut], q[keep & ~cut])
    assert 4.0 not in np.round(t0, 6)
    assert len(t0) == 8  # windows starting at 4 and 5 need t = 5: both gone
    np.testing.assert_allclose(rpe, 0.05 * sp, rtol=1e-9)


def test_too_few_windows_is_an_error():
    with pytest.raises(ValueError, match="at least 3"):
        speed_statistic(np.array([1.0, 2.0]), np.array([0.1, 0.2]))


# The three real pairs of ../shared/data/real: (truth file, fast/slow ratio, rho) measured.
REAL_PAIRS = {
    "euroc_v102_rpg": ("groundtruth_tum.txt", 1.83, 0.39),
    "euroc_mh04_rpg": ("groundtruth_tum.txt", 1.29, 0.18),  # truth jumps made gaps (was 1.23)
    "euroc_v102": ("groundtruth.csv", 1.30, 0.34),
}
# The real range of the statistic, from those pairs (1.29 to 1.83).
REAL_RATIO = (min(v[1] for v in REAL_PAIRS.values()), max(v[1] for v in REAL_PAIRS.values()))


@pytest.mark.real
@pytest.mark.slow
def test_real_vio_errs_more_when_flown_faster(real_data, tmp_path):
    """The three EuRoC pairs, ingested from their text files (SE(3) alignment, dt 0.1 s):
    every one has a larger 1 s RPE in its fastest third of windows (measured 1.83, 1.29,
    1.30; rho 0.39, 0.18, 0.34)."""
    from qsls.pipeline.ingest.flight import Flight
    from qsls.pipeline.ingest.stage import IngestOptions, ingest

    for name, (truth, ratio, rho) in REAL_PAIRS.items():
        o = IngestOptions(
            vio=real_data / name / "estimate_tum.txt", truth=real_data / name / truth,
            align="se3", dt=0.1,
        )  # fmt: skip
        ingest([], o, tmp_path / name)
        f = Flight.load(tmp_path / name)
        st = rpe_vs_speed(f.frame["t"].to_numpy(), f.states(), f.measurements())
        assert st.windows >= 60
        assert st.ratio == pytest.approx(ratio, abs=0.05) and st.ratio > 1.1
        assert st.rho == pytest.approx(rho, abs=0.05) and st.rho > 0.1


@pytest.mark.parametrize("perception", ["regular", "degraded"])
def test_emulated_flight_at_euroc_speeds_falls_in_the_real_range(perception):
    """A closed-loop PD flight over a figure eight (0.6 to 1.3 m/s, EuRoC-like) on the default
    emulator: its fast/slow RPE ratio lies in the real range; with the position steps of the
    ridges' first design (velocity steps and Lipschitz constant as the defaults') it lies well
    above it."""
    from qsls.pipeline.sim.closedloop import FlightOptions, fly
    from qsls.pipeline.sim.vio import RIDGE_VELOCITY_SCALE, VioEmulator, VioParams, scaled_ridges

    def ratio(vio: dict) -> float:
        o = FlightOptions.model_validate(
            {
                "controller": {"kind": "pd"},
                "reference": {"kind": "figure8", "radius": 1.5, "period": 10.0, "laps": 6},
                "vio": {"perception": perception, **vio},
            }
        )
        log = fly(o, seed=0)
        k = slice(None, None, round(o.vio.rate_hz * DT))
        st = rpe_vs_speed(log.vio_t_ns[k] * 1e-9, log.vio_x[k], log.vio_y[k])
        assert st.windows >= 60 and st.rho > 0.1
        return st.ratio

    first = [r.model_dump() for r in scaled_ridges(1.0, RIDGE_VELOCITY_SCALE)]
    lipschitz = VioEmulator(VioParams.model_validate({"ridges": first}), 0).lipschitz
    assert VioEmulator(VioParams(), 0).lipschitz == pytest.approx(lipschitz, rel=1e-12)
    assert lipschitz == pytest.approx(0.209, rel=1e-12)  # the first design's L
    assert REAL_RATIO[0] <= ratio({}) <= REAL_RATIO[1]
    assert ratio({"ridges": first}) > REAL_RATIO[1] + 0.5
