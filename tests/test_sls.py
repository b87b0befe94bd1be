"""The FIR SLS problem against independent references (LQG, transfer functions, limits)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from qsls.pipeline.control import certify, largest_s, sls
from qsls.pipeline.control.guarantee import Norms, robustness_lhs
from qsls.pipeline.control.nominal import pd_responses
from qsls.pipeline.control.pdgain import PDGains
from qsls.pipeline.control.realize import RealizedController, filter_bank
from qsls.pipeline.control.status import CERTIFIED, FAILED, RELAXED
from qsls.pipeline.core.plant import quadrotor_model
from qsls.pipeline.premise.numbers import PremiseNumbers
from tests.lqg_reference import lqg_h2_squared

Q = np.diag([10.0, 10, 10, 1, 1, 1])
R = np.diag([1.0, 1, 0.1])
MODEL = quadrotor_model()
NOMINAL = replace(sls.NO_PREMISE, eps_w=0.01, eps=0.05)
ROBUST = PremiseNumbers(eps=0.05, S=0.1, radius=1.0, eps_w=0.01, delta=0.05)


@pytest.mark.parametrize(("strictly_proper", "design_value"), [(False, 152.1087), (True, 189.1760)])
def test_h2_without_robustness_equals_lqg(strictly_proper, design_value):
    """H2 synthesis at T = 60 == the Riccati/Lyapunov LQG cost (current-estimate form when
    Phi_uy(0) is free, predictor form when strictly proper), and the figures of docs/synthesis.md#costs."""
    m = MODEL
    ref = lqg_h2_squared(m.A, m.B, m.C, m.H, Q, R, 1.0, 0.5, strictly_proper=strictly_proper)
    sol = sls.solve(
        m,
        sls.Structure(60, "h2", "qr", False, strictly_proper),
        sls.Values(Q=Q, R=R, numbers=replace(sls.NO_PREMISE, eps_w=1.0, eps=0.5)),
    )
    assert sol.status == "optimal"
    # the optimum, and the H2 cost recomputed from the taps
    assert sol.objective == pytest.approx(ref, rel=1e-6)
    recomputed = sls.cost_value("h2", sol.taps, m, np.sqrt(Q), np.sqrt(R), 1.0, 0.5) ** 2
    assert recomputed == pytest.approx(ref, rel=1e-6)
    assert ref == pytest.approx(design_value, abs=1e-4)
    if strictly_proper:
        assert np.abs(sol.taps.Phi_uy[0]).max() < 1e-9
    else:
        assert np.abs(sol.taps.Phi_uy[0]).max() > 0.1  # the current estimate uses y[k]


def test_min_phi_xy_at_least_one_and_design_figures():
    got = {T: largest_s.min_phi_xy(MODEL, T) for T in (10, 20)}
    assert got[10] == pytest.approx(3.4, abs=0.05)
    assert got[20] == pytest.approx(2.16, abs=0.01)
    assert got[20] >= 1.0 and got[10] > got[20]
    # independent of the mass (docs/synthesis.md#the-robustness-constraint)
    assert largest_s.min_phi_xy(quadrotor_model(mass=1.3), 20) == pytest.approx(got[20], rel=1e-6)


def test_position_block_dc_gain_is_minus_identity():
    """Why ||Phi_xy|| >= 1: at z = 1 the position block of any achievable Phi_xy is -I."""
    sol = sls.solve(MODEL, sls.Structure(15, "l1", "qr", False), sls.Values(numbers=NOMINAL))
    dc = sol.taps.Phi_xy.sum(axis=0)[:3, :3]
    np.testing.assert_allclose(dc, -np.eye(3), atol=1e-8)
    assert sls.l1_norm(sol.taps.Phi_xy) >= 1.0


def _tf(taps: np.ndarray, z: complex, offset: int = 0) -> np.ndarray:
    return sum(t * z ** (-(k + offset)) for k, t in enumerate(taps))


@pytest.mark.parametrize("strictly_proper", [False, True])
def test_filter_bank_equals_sls_controller_transfer_function(strictly_proper):
    """The realization's transfer function equals K = Phi_uy - Phi_ux Phi_xx^-1 Phi_xy
    (paper), evaluated at points on and off the unit circle."""
    sol = sls.solve(
        MODEL,
        sls.Structure(12, "l1", "qr", True, strictly_proper),
        sls.Values(numbers=replace(ROBUST, S=0.15)),
    )
    t = sol.taps
    bank = filter_bank(t)
    nx, T = 6, t.T
    kb = bank.K_bb.reshape(nx, T - 1, nx).transpose(1, 0, 2)
    kby = bank.K_by.reshape(nx, T, 6).transpose(1, 0, 2)
    kub = bank.K_ub.reshape(3, T, nx).transpose(1, 0, 2)
    kuy = bank.K_uy.reshape(3, T + 1, 6).transpose(1, 0, 2)
    for z in (np.exp(0.3j), np.exp(2.0j), 1.7 + 0.4j):
        k_sls = _tf(t.Phi_uy, z) - _tf(t.Phi_ux, z) @ np.linalg.solve(
            _tf(t.Phi_xx, z), _tf(t.Phi_xy, z)
        )
        beta = np.linalg.solve(z * np.eye(nx) - _tf(kb, z), _tf(kby, z))
        k_bank = _tf(kub, z) @ beta + _tf(kuy, z)
        np.testing.assert_allclose(k_bank, k_sls, atol=1e-7 * max(1, np.abs(k_sls).max()))


def test_max_feasible_s_is_feasible_and_one_percent_more_is_not():
    given = PremiseNumbers(eps=0.05, S=0.0, radius=1.0, eps_w=0.01, delta=0.05)
    ms = largest_s.max_feasible_s(MODEL, 12, given)
    st = sls.Structure(12, "l1", "qr", True)
    numbers = replace(given, S=ms.s_max)
    ok = sls.solve(MODEL, st, sls.Values(numbers=numbers))
    assert ok.status == "optimal"
    norms = Norms(sls.l1_norm(ok.taps.Phi_xy), sls.l1_norm(ok.taps.Phi_xx), 0.0)
    lhs = robustness_lhs(numbers, norms)
    assert lhs < 1.0
    assert (
        sls.solve(MODEL, st, sls.Values(numbers=replace(numbers, S=1.01 * ms.s_max))).status
        == "infeasible"
    )
    # no Delta, no process noise: S_max = 1 / min ||Phi_xy|| - eps_e / r
    ms0 = largest_s.max_feasible_s(MODEL, 12, replace(sls.NO_PREMISE, eps=0.05))
    assert ms0.s_max == pytest.approx(1 / largest_s.min_phi_xy(MODEL, 12) - 0.05, rel=1e-5)


def test_pd_responses_match_a_simulated_pd_loop():
    """The PD's truncated responses = the closed loop simulated step by step."""
    K, taps = pd_responses(MODEL, PDGains(), 25)
    xs, us = certify.closed_loop_impulses(MODEL, _StaticBank(K), 26)
    np.testing.assert_allclose(xs, np.concatenate([taps.Phi_xx, taps.Phi_xy], axis=2), atol=1e-12)
    np.testing.assert_allclose(us, np.concatenate([taps.Phi_ux, taps.Phi_uy], axis=2), atol=1e-12)


class _StaticBank:
    """A static gain dressed as a filter bank of horizon 2 (K_uy tap 0 only)."""

    def __init__(self, K):
        self.K_bb = np.zeros((6, 6))
        self.K_by = np.zeros((6, 12))
        self.K_ub = np.zeros((3, 12))
        self.K_uy = np.hstack([K, np.zeros((3, 12))])
        self.nx, self.nu, self.ny, self.T = 6, 3, 6, 2


def test_realized_controller_single_and_batch_steps_agree():
    sol = sls.solve(MODEL, sls.Structure(10, "l1", "qr", False), sls.Values(numbers=NOMINAL))
    bank = filter_bank(sol.taps)
    rng = np.random.default_rng(1)
    ys = rng.normal(size=(30, 6, 3))
    batch = RealizedController(bank, 0.1)
    batch.reset(3)
    out_b = np.stack([batch.step(y) for y in ys])
    for j in range(3):
        c = RealizedController(bank, 0.1)
        out = np.stack([c.step(y[:, j]) for y in ys])
        np.testing.assert_allclose(out, out_b[:, :, j], atol=1e-12)
    # the impulse response of the controller alone is the convolution of its taps: u[0] = Phi_uy(0) y[0]
    c = RealizedController(bank, 0.1)
    y0 = rng.normal(size=6)
    np.testing.assert_allclose(c.step(y0), sol.taps.Phi_uy[0] @ y0, atol=1e-12)


def test_bad_horizon_and_weights():
    with pytest.raises(ValueError, match="at least 2"):
        sls.SLSProblem(MODEL, sls.Structure(1))
    with pytest.raises(ValueError, match="positive definite"):
        sls.psd_sqrt(np.diag([1.0, 0.0, 1.0]), "R")


@pytest.mark.parametrize("full_q", [False, True])
def test_l1_cost_optimum_matches_the_cost_recomputed_from_taps(full_q):
    """The solver's optimum is c_QR (L1) of its taps, computed here from the definition:
    the largest absolute row sum of diag(Q^1/2, R^1/2) [Phi] diag(eps_w H, eps_e I)."""
    from scipy.linalg import sqrtm

    q = Q.copy()
    if full_q:
        q[0, 3] = q[3, 0] = 1.5  # still positive definite
    v = sls.Values(Q=q, R=R, numbers=replace(ROBUST, eps_w=0.02))
    sol = sls.solve(MODEL, sls.Structure(8, "l1", "qr", True), v)
    assert sol.status == "optimal"
    t = sol.taps
    qh, rh = np.real(sqrtm(q)), np.real(sqrtm(R))
    top = np.hstack(
        [qh @ t.Phi_xx[k] * 0.02 for k in range(9)] + [qh @ t.Phi_xy[k] * 0.05 for k in range(9)]
    )
    bot = np.hstack(
        [rh @ t.Phi_ux[k] * 0.02 for k in range(9)] + [rh @ t.Phi_uy[k] * 0.05 for k in range(9)]
    )
    want = np.abs(np.vstack([top, bot])).sum(axis=1).max()
    assert sol.objective == pytest.approx(want, rel=1e-7)


def test_solver_trouble_is_never_certified():
    v = sls.Values(numbers=ROBUST)
    prob = sls.SLSProblem(MODEL, sls.Structure(10, "l1", "qr", True))
    sol = prob.solve(v, solver_options={"max_iter": 3})
    assert sol.status in ("inaccurate", "error")
    if sol.taps is not None:
        setting = PremiseNumbers(eps=0.05, S=0.1, radius=1.0, eps_w=0.01, delta=0.05, R0=0.05)
        c = certify.certify(sol.taps, MODEL, setting, solver_status=sol.status)
        assert c.status != CERTIFIED and not c.checks["solver"]["passed"]


def test_certificate_checks_catch_a_wrong_response():
    """Perturb one tap of an achievable response: achievability, realization and status fail."""
    from dataclasses import replace

    sol = sls.solve(
        MODEL,
        sls.Structure(10, "l1", "qr", True),
        sls.Values(numbers=ROBUST),
    )
    setting = PremiseNumbers(eps=0.05, S=0.1, radius=1.0, eps_w=0.01, delta=0.05, R0=0.05)
    c = certify.certify(sol.taps, MODEL, setting)
    assert c.status == RELAXED and c.realization_error < 1e-12
    bad_uy = sol.taps.Phi_uy.copy()
    bad_uy[4, 0, 0] += 1e-5
    c = certify.certify(replace(sol.taps, Phi_uy=bad_uy), MODEL, setting)
    assert c.status == FAILED
    assert c.achievability_residual > 1e-7 and not c.checks["achievability"]["passed"]
    assert c.realization_error > 1e-8 and not c.checks["realization"]["passed"]
