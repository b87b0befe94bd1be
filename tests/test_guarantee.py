"""The generalized theorem (docs/guarantee.md) against brute force, and its special case.

The closed loop is ``x_k = x_hat_k + sum_{t=1}^{T} Phi_xy(t) e_{k-t}``, with ``dist(x_hat_k) <= a``;
whatever ``Phi_xy`` and however the errors are chosen within the premise (dense part
``|d_k|_e <= eps + S dist(x_k)``, at most ``m`` outliers of size ``eps_o`` on the velocity channels
in any ``T`` consecutive steps), the theorem says ``dist(x_k) <= rho*``.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from qsls.pipeline.control import largest_s, sls
from qsls.pipeline.control.certify import certify
from qsls.pipeline.control.guarantee import (
    VELOCITY,
    Norms,
    guarantee,
    min_norm_bound,
    necessary_condition,
    rho_star,
    sparse_gain,
    system_norms,
)
from qsls.pipeline.control.status import RELAXED
from qsls.pipeline.core.plant import quadrotor_model
from qsls.pipeline.premise import honest
from qsls.pipeline.premise.numbers import PremiseNumbers

WX = np.array([1.0, 1.0, 1.0, 0.5, 0.5, 0.5])
WE = np.array([1.0, 1.0, 1.0, 0.5, 0.5, 0.5])


def _random_phi(rng: np.random.Generator, T: int) -> np.ndarray:
    phi = rng.normal(size=(T + 1, 6, 6)) * rng.uniform(0.01, 0.1, size=(T + 1, 1, 1))
    phi[0] = 0.0  # x_k never depends on e_k
    return phi


def _simulate(phi, x_hat, numbers, m, rng, adversary):
    """Brute-force closed loop with the training set {0} (so dist(x) = |x|_x). Returns the
    largest dist(x_k) and the largest |d_k|_e."""
    T = phi.shape[0] - 1
    K = len(x_hat)
    e = np.zeros((K, 6))
    out_count = np.zeros(K, dtype=int)
    worst_d, worst_dense = 0.0, 0.0
    for k in range(K):
        x = x_hat[k] + sum(phi[t] @ e[k - t] for t in range(1, min(T, k) + 1))
        dist = float(np.abs(WX * x).max())
        worst_d = max(worst_d, dist)
        allowed = numbers.eps + numbers.S * dist
        signs = adversary(k, x)
        d = allowed * signs / WE
        worst_dense = max(worst_dense, float(np.abs(WE * d).max()))
        o = np.zeros(6)
        recent = out_count[max(0, k - T + 1) : k].sum()
        if m and recent < m and rng.random() < 0.5:
            o[list(VELOCITY)] = numbers.eps_o * rng.choice([-1.0, 1.0], size=3)
            out_count[k] = 1
        e[k] = d + o
    return worst_d, worst_dense


@pytest.mark.parametrize("seed", range(6))
def test_random_adversaries_never_leave_rho_star(seed):
    rng = np.random.default_rng(seed)
    T, m = 8, 2
    phi = _random_phi(rng, T)
    norms = system_norms(phi, np.zeros_like(phi), state_scale=WX, error_scale=WE,
                         outlier_channels=VELOCITY, m=m)  # fmt: skip
    S = 0.5 / norms.N  # S N = 0.5
    numbers = PremiseNumbers(eps=0.05, S=S, radius=10.0, eps_w=0.0, delta=0.1, eps_o=0.3, m=m)
    rho = rho_star(numbers, norms)
    a = numbers.delta
    K = 60
    worst = 0.0
    for trial in range(20):
        direction = rng.choice([-1.0, 1.0], size=6)
        x_hat = np.tile(a * direction / WX, (K, 1)) * rng.uniform(0.5, 1.0, size=(K, 1))

        def adversary(k, x, trial=trial):
            if trial % 2:
                return rng.choice([-1.0, 1.0], size=6)
            # align every channel with the row that is largest now, through tap 1
            i = int(np.argmax(np.abs(WX * x)))
            return np.sign(phi[1][i] + 1e-15) * np.sign(x[i] + 1e-15)

        d_max, dense_max = _simulate(phi, x_hat, numbers, m, rng, adversary)
        worst = max(worst, d_max / rho)
        assert d_max <= rho * (1 + 1e-12)
        assert dense_max <= numbers.eps + S * rho + 1e-12
    assert worst > 0.2  # the adversaries do push: the test is not vacuous


def test_rho_star_is_reached_by_the_worst_case_at_S0():
    """With S = 0 the bound is tight: errors aligned with the signs of one row of Phi_xy
    (dense part at eps, outliers on the m taps of largest gain) reach rho* exactly."""
    rng = np.random.default_rng(7)
    T, m = 10, 3
    phi = _random_phi(rng, T)
    norms = system_norms(phi, np.zeros_like(phi), state_scale=WX, error_scale=WE,
                         outlier_channels=VELOCITY, m=m)  # fmt: skip
    numbers = PremiseNumbers(eps=0.1, S=0.0, radius=10.0, eps_w=0.0, delta=0.2, eps_o=0.5, m=m)
    # the row that sets N is also the one that sets rho* here only by chance: search all rows
    best = 0.0
    for i in range(6):
        e = np.zeros((T + 1, 6))  # e[t] is the error t steps before k
        for t in range(1, T + 1):
            e[t] = numbers.eps * np.sign(phi[t][i]) / WE
        per_tap = np.abs(phi[1:, i, list(VELOCITY)]).sum(axis=1)
        for t in np.argsort(-per_tap)[:m] + 1:
            e[t, list(VELOCITY)] += numbers.eps_o * np.sign(phi[t][i, list(VELOCITY)])
        x = numbers.delta / WX[i] + sum(phi[t][i] @ e[t] for t in range(1, T + 1))
        best = max(best, WX[i] * x)
    # rho* = a + N eps + eps_o G_m is attained when one row carries both maxima
    assert best <= rho_star(numbers, norms) * (1 + 1e-12)
    rows = []
    for i in range(6):
        dense = numbers.eps * WX[i] * np.abs(phi[1:, i, :] / WE).sum()
        per_tap = np.abs(phi[1:, i, list(VELOCITY)]).sum(axis=1)
        sparse = numbers.eps_o * WX[i] * np.sort(per_tap)[::-1][:m].sum()
        rows.append(numbers.delta + dense + sparse)
    assert best == pytest.approx(max(rows), rel=1e-12)


def test_sparse_gain_is_the_peak_over_m_sparse_inputs():
    rng = np.random.default_rng(3)
    T, m = 6, 2
    phi = _random_phi(rng, T)
    g = sparse_gain(phi, WX, VELOCITY, m)
    brute = 0.0
    for taps in itertools.combinations(range(1, T + 1), m):
        for i in range(6):
            brute = max(brute, WX[i] * sum(np.abs(phi[t][i, list(VELOCITY)]).sum() for t in taps))
    assert g == pytest.approx(brute, rel=1e-14)
    assert sparse_gain(phi, WX, VELOCITY, 0) == 0.0


def test_special_case_is_dean_et_al():
    """W = I, no outliers: the certificate's numbers are today's formula on a real synthesis."""
    model = quadrotor_model()
    S, eps, r, eps_w, delta = 0.05, 0.1, 1.0, 0.01, 0.05
    numbers = PremiseNumbers(eps=eps, S=S, radius=r, eps_w=eps_w, delta=delta)
    sol = sls.solve(model, sls.Structure(20, "l1", "qr", True), sls.Values(numbers=numbers))
    assert sol.taps is not None
    n_xy = sls.l1_norm(sol.taps.Phi_xy)
    n_xx = sls.l1_norm(sol.taps.Phi_xx, model.H)
    c = certify(sol.taps, model, numbers)
    a = eps_w * n_xx + delta
    assert c.status == RELAXED and c.checks["robustness"]["passed"]
    assert c.robustness_lhs == pytest.approx((S + eps / r) * n_xy + a / r, rel=1e-12)
    assert c.gamma == pytest.approx((eps + S * a) / (1 - S * n_xy), rel=1e-12)
    assert c.gamma_strict == pytest.approx(eps / (1 - S * n_xy), rel=1e-12)
    assert c.norm_N == pytest.approx(n_xy, rel=1e-14) and c.G_m == 0.0
    assert c.rho_star <= r


def test_generalized_synthesis_meets_its_own_constraint():
    """Position-only measurement with weights and outliers in the constraint: the solver's
    answer, re-checked from its taps, satisfies the constraint, reads no velocity error, and
    the bound is strictly below r."""
    model = quadrotor_model()
    for measure, m in (("position", 0), ("full", 3)):
        shape = sls.Shape((1, 1, 1, 0.5, 0.5, 0.5), (1, 1, 1, 0.5, 0.5, 0.5), measure, m)
        numbers = PremiseNumbers(eps=0.02, S=0.01, radius=1.5, eps_w=0.005, delta=0.05,
                                 eps_o=0.2, m=m)  # fmt: skip
        st = shape.structure(20, "qr", False)
        rob = sls.Structure(**{**st.__dict__, "robust": True})
        sol = sls.solve(model, rob, sls.Values(numbers=numbers))
        assert sol.taps is not None, (measure, sol.solver_status)
        c = certify(sol.taps, model, numbers, shape)
        assert c.status == RELAXED and c.checks["robustness"]["passed"], c.checks
        assert c.robustness_lhs <= 1 - sls.ROBUST_BACKOFF + 1e-7
        if measure == "position":
            assert np.abs(sol.taps.Phi_uy[:, :, 3:]).max() == 0.0
            assert np.abs(sol.taps.Phi_xy[:, :, 3:]).max() < 1e-9
        else:
            assert c.G_m > 0
        g = guarantee(numbers, Norms(c.norm_N, c.norm_N_w, c.G_m))
        assert g.rho_star < 1.5 and g.dense_bound == pytest.approx(0.02 + 0.01 * g.rho_star)


def test_lofo_slope_and_tested_range():
    """Two flights: the left-out one exceeds the other's max by 0.1 at distance 0.5 -> S 0.2."""
    x = np.zeros((4, 6))
    x[2:, 0] = 0.5
    dense = np.array([0.1, 0.1, 0.2, 0.1])
    flight = np.array([0, 0, 1, 1])
    dist = honest.other_flight_distances(x, flight, np.ones(6))
    assert dist.tolist() == [0.5, 0.5, 0.5, 0.5]
    fit = honest.lofo_slope(dense, flight, dist, radius=1.0)
    assert pytest.approx(0.2) == fit.S and fit.per_flight == (0.0, pytest.approx(0.2))
    assert fit.tested_range == 0.5 and fit.n_tested == 4
    assert math.isnan(honest.lofo_slope(dense, np.zeros(4, int), dist, 1.0).S)


def test_outlier_windows_and_m():
    nz = np.array([1, 0, 0, 1, 1, 0, 0, 0, 1, 0], dtype=bool)
    flight = np.zeros(10, dtype=int)
    counts = honest.window_counts(nz, flight, 3)
    assert counts.tolist() == [1, 1, 1, 1, 2, 2, 1, 0, 1, 1]
    o = np.zeros((10, 6))
    o[nz, 3] = 0.4
    fit = honest.fit_outliers(o, flight, window=3, risk=1e-3)
    assert fit.n_outliers == 4 and fit.max_in_window == 2
    assert fit.m >= 2 and honest.window_exceed_prob(fit.m, 3, fit.rate_upper) <= 1e-3
    lo, hi = honest.clopper_pearson(4, 10)
    assert 0.12 < lo < 0.13 and 0.73 < hi < 0.74  # the textbook interval for 4 of 10


@pytest.mark.parametrize(
    ("state_scale", "error_scale"),
    [
        ((1,) * 6, (4,) * 6),
        ((1,) * 6, (0.5, 0.5, 0.5, 1, 1, 1)),
        ((1, 1, 1, 0.5, 0.5, 0.5), (0.3, 2, 1, 1, 1, 1)),
    ],
)
def test_necessary_condition_is_necessary_with_weights(state_scale, error_scale):
    """``N_lower = max_i w_x,i / w_e,i`` lies below the smallest achievable ``N`` (the taps of
    ``Phi_xy`` sum to ``-I`` on the positions), so a point that fails the weighted condition
    is infeasible; with ``W_e = 4 I`` the unweighted ``S + eps/r < 1`` would refuse a point the
    solver finds feasible (a review found the sweep skipping it)."""
    model = quadrotor_model()
    shape = sls.Shape(state_scale, error_scale, "full")
    st = shape.structure(10, "min_phi_xy", False)
    sol = sls.solve(model, st, sls.Values())
    assert sol.taps is not None
    np.testing.assert_allclose(np.diag(sol.taps.Phi_xy.sum(axis=0))[:3], -1.0, atol=1e-7)
    n_min = largest_s.min_phi_xy(model, 10, shape=shape)
    assert min_norm_bound(state_scale, error_scale) <= n_min + 1e-9
    if error_scale == (4,) * 6:
        numbers = PremiseNumbers(eps=0.6, S=0.5, radius=1.0, eps_w=0.0, delta=0.0)
        assert numbers.S + numbers.eps / numbers.radius >= 1.0  # the old condition refused it
        assert necessary_condition(numbers, state_scale, error_scale) < 1.0
        ms = largest_s.max_feasible_s(model, 10, numbers, shape=shape)
        assert ms.s_max > 0.5
        rob = sls.Structure(**{**shape.structure(10, "qr", False).__dict__, "robust": True})
        values = sls.Values(
            numbers=PremiseNumbers(eps=0.6, S=0.5, radius=1.0, eps_w=0.0, delta=0.0)
        )
        assert sls.solve(model, rob, values).solver_status == "optimal"
