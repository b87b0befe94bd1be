"""The checks behind every certificate (docs/synthesis.md#the-checks-behind-a-certificate).

A controller is ``certified`` only when all of these pass, each recomputed from the taps
that are stored (never from the solver's own report):

- achievability: every equation of :func:`qsls.pipeline.control.sls.achievability_residuals`
  holds to ``ACHIEVABILITY_TOL`` (max absolute residual);
- realization: the closed loop of the plant and the realized filter bank, driven by an
  impulse in each state-disturbance and each measurement-error channel, reproduces the
  taps ``Phi`` (and is zero after tap ``T``) to ``REALIZATION_TOL`` (max absolute error
  scaled by ``max(1, max |Phi|)``);
- internal stability: with random plant state and random controller memory (``beta`` and
  past ``y``) and no input, the closed loop returns to zero and its peak stays bounded;
- measured channels: with ``measure: position`` the taps of ``Phi_uy`` on the velocity
  errors are zero (the controller never reads them);
- guarantee (:mod:`qsls.pipeline.control.guarantee`, docs/guarantee.md): ``lhs = (S + eps/r) N
  + (a + eps_o G_m)/r < 1`` and ``rho* = (a + N eps + eps_o G_m)/(1 - S N) <= r``, so the dense
  error stays below ``gamma = eps + S rho*``; the paper's ``gamma_strict = R0 / (1 - S N)``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from qsls.pipeline.control import sls
from qsls.pipeline.control.body import CertificateBody
from qsls.pipeline.control.guarantee import (
    Norms,
    guarantee,
    measured_channels,
    outlier_channels,
    velocity_deviation,
)
from qsls.pipeline.control.realize import FilterBank, RealizedController, filter_bank
from qsls.pipeline.control.sls import Taps
from qsls.pipeline.control.status import (
    FAILED,
    REFERENCE,
    RELAXED,
    SOLVER_INACCURATE,
    UNCERTIFIED,
    Status,
)
from qsls.pipeline.core.plant import LinearModel
from qsls.pipeline.premise.numbers import PremiseNumbers

NOT_CALIBRATED = (
    "not calibrated: the premise describes the design flights only; calibrate it on flights "
    "this controller flies (qsls calibrate, docs/calibration.md)"
)
PREMISE_VIOLATED = "part of the training data violates the premise (its shares under premise)"
ACHIEVABILITY_TOL = 1e-7
REALIZATION_TOL = 1e-8
PERTURBATION_TOL = 1e-8  # final / initial size after the perturbation has had 4T steps


def closed_loop_impulses(
    model: LinearModel, bank: FilterBank, steps: int
) -> tuple[np.ndarray, np.ndarray]:
    """Simulate plant + filter bank for an impulse at k = 0 in each of the ``nx`` state
    disturbance channels (entering as ``x[1] = d``) and ``ny`` measurement channels.

    Returns ``x`` ``(steps, nx, nx+ny)`` and ``u`` ``(steps, nu, nx+ny)``: column ``i`` of
    tap ``k`` is the response at time ``k`` to impulse ``i``; for an achievable ``Phi``
    they equal ``[Phi_xx(k) Phi_xy(k)]`` and ``[Phi_ux(k) Phi_uy(k)]``.
    """
    a, b, c = model.A, model.B, model.C
    nx, ny = model.nx, model.ny
    m = nx + ny
    ctrl = RealizedController(bank, model.dt)
    ctrl.reset(m)
    x = np.zeros((nx, m))
    d0 = np.hstack([np.eye(nx), np.zeros((nx, ny))])
    e0 = np.hstack([np.zeros((ny, nx)), np.eye(ny)])
    xs = np.zeros((steps, nx, m))
    us = np.zeros((steps, bank.nu, m))
    for k in range(steps):
        y = c @ x + (e0 if k == 0 else 0.0)
        u = ctrl.step(y)
        xs[k], us[k] = x, u
        x = a @ x + b @ u + (d0 if k == 0 else 0.0)
    return xs, us


def realization_error(taps: Taps, model: LinearModel, bank: FilterBank | None = None) -> float:
    """Max |closed-loop impulse response - Phi| over ``2T + 2`` steps, scaled by
    ``max(1, max |Phi|)``."""
    bank = bank or filter_bank(taps)
    T = taps.T
    steps = 2 * T + 2
    xs, us = closed_loop_impulses(model, bank, steps)
    want_x = np.zeros_like(xs)
    want_u = np.zeros_like(us)
    want_x[: T + 1] = np.concatenate([taps.Phi_xx, taps.Phi_xy], axis=2)
    want_u[: T + 1] = np.concatenate([taps.Phi_ux, taps.Phi_uy], axis=2)
    scale = max(1.0, *(float(np.abs(p).max()) for p in taps.arrays().values()))
    return float(max(np.abs(xs - want_x).max(), np.abs(us - want_u).max()) / scale)


def perturbation_response(
    model: LinearModel, bank: FilterBank, *, seed: int = 0, copies: int = 4
) -> tuple[float, float]:
    """Closed loop with no input from a random plant state and random controller memory
    (``beta`` and past ``y``, each entry uniform in [-1, 1]). Returns ``(peak, final)``:
    the largest absolute value of ``x``, ``u`` and the memory over ``4T + 10`` steps, and
    their largest absolute value over the last ``T`` steps, both relative to the initial
    perturbation's size."""
    rng = np.random.default_rng(seed)
    a, b, c = model.A, model.B, model.C
    ctrl = RealizedController(bank, model.dt)
    ctrl.reset(copies)
    ctrl.beta[:] = rng.uniform(-1, 1, ctrl.beta.shape)
    ctrl.ys[:] = rng.uniform(-1, 1, ctrl.ys.shape)
    x = rng.uniform(-1, 1, (model.nx, copies))
    T = bank.T
    steps = 4 * T + 10
    sizes = np.zeros(steps)
    for k in range(steps):
        u = ctrl.step(c @ x)
        sizes[k] = max(
            np.abs(x).max(), np.abs(u).max(), np.abs(ctrl.beta).max(), np.abs(ctrl.ys).max()
        )
        x = a @ x + b @ u
    return float(sizes.max()), float(sizes[-T:].max())


def guarantee_fields(numbers: PremiseNumbers, norms: Norms) -> dict[str, float]:
    """The certificate's guarantee numbers (:func:`qsls.pipeline.control.guarantee.guarantee`):
    ``robustness_lhs``, ``margin``, ``a``, ``rho_star``, ``gamma`` (the dense bound
    ``eps + S rho*``), ``gamma_strict`` and the system quantities ``N``, ``N_w``, ``G_m``."""
    g = guarantee(numbers, norms)
    return {
        "robustness_lhs": g.robustness_lhs,
        "margin": g.margin,
        "s_times_norm_phi_xy": g.s_times_n,
        "a": g.a,
        "rho_star": g.rho_star,
        "gamma": g.dense_bound,
        "gamma_strict": g.gamma_strict,
        "norm_N": norms.N,
        "norm_N_w": norms.N_w,
        "G_m": norms.G_m,
        "G_b": norms.G_b,
    }


def certify(
    taps: Taps,
    model: LinearModel,
    numbers: PremiseNumbers,
    shape: sls.Shape = sls.Shape(),
    *,
    solver_status: str = "optimal",
    reference: bool = False,
    premise_holds: bool = True,
) -> CertificateBody:
    """Run every check on ``taps``: the certificate's body, its ``status`` one of
    :data:`Status` (a ``reference`` controller is measured, not checked)."""
    bank = filter_bank(taps)
    residuals = sls.achievability_residuals(taps, model)
    resid = max(residuals.values())
    norms = shape.norms(taps, model)
    g = guarantee_fields(numbers, norms)
    fields: dict[str, Any] = {
        "norm_phi_xx_h": sls.l1_norm(taps.Phi_xx, model.H),  # ||Phi_xx H|| (H = I by default)
        "norm_phi_xy": sls.l1_norm(taps.Phi_xy),
        "norm_phi_ux": sls.l1_norm(taps.Phi_ux, model.H),
        "norm_phi_uy": sls.l1_norm(taps.Phi_uy),
        **g,
        "achievability_residual": resid,
    }
    if reference:
        return CertificateBody(status=REFERENCE, truncation_residual=resid, **fields)
    rerr = realization_error(taps, model, bank)
    peak, final = perturbation_response(model, bank)
    fields["realization_error"] = rerr
    fields["perturbation_peak"] = peak
    fields["perturbation_final"] = final
    checks = _checks(solver_status, resid, rerr, peak, final, _unread_gain(taps, shape))
    checks["robustness"] = {
        "value": g["robustness_lhs"],
        "limit": 1.0,
        "passed": g["robustness_lhs"] < 1.0 and g["rho_star"] <= numbers.radius,
    }
    if numbers.gate is not None and shape.gate:
        rho_v = velocity_deviation(
            taps.Phi_xy, taps.Phi_xx @ model.H, numbers, error_scale=shape.error_scale,
            measured=measured_channels(shape.measure),
            outlier_channels=outlier_channels(shape.measure, shape.m),
            bias_dirs=model.bias_dirs,
        )  # fmt: skip
        fields["rho_v"] = rho_v
        ok = rho_v <= numbers.gate * (1 + 1e-7)
        checks["robustness"]["passed"] = bool(checks["robustness"]["passed"] and ok)
        checks["gate"] = {"value": rho_v, "limit": numbers.gate, "passed": bool(ok)}
    fields["checks"] = checks
    status, reason = _status(checks, solver_status, float(g["gamma"]), premise_holds)
    return CertificateBody(status=status, status_reason=reason, **fields)


def _checks(
    solver_status: str, resid: float, rerr: float, peak: float, final: float, unread: float
) -> dict[str, dict[str, Any]]:
    """The checks of the taps themselves (the guarantee's are added by :func:`certify`)."""
    return {
        "solver": {"value": solver_status, "passed": solver_status == "optimal"},
        "achievability": {
            "value": resid,
            "limit": ACHIEVABILITY_TOL,
            "passed": resid <= ACHIEVABILITY_TOL,
        },
        "realization": {"value": rerr, "limit": REALIZATION_TOL, "passed": rerr <= REALIZATION_TOL},
        "internal_stability": {
            "value": final,
            "limit": PERTURBATION_TOL,
            "passed": bool(np.isfinite(peak) and final <= PERTURBATION_TOL),
        },
        "measured_channels": {
            "value": unread,
            "limit": ACHIEVABILITY_TOL,
            "passed": unread <= ACHIEVABILITY_TOL,
        },
    }


def _status(
    checks: dict[str, dict[str, Any]], solver_status: str, gamma: float, premise_holds: bool
) -> tuple[Status, str | None]:
    """The status the checks allow, and why it is not ``certified``: a premise fitted on the
    design flights describes them, not the next flight; only a calibration (qsls calibrate)
    makes a certificate ``certified``."""
    verified = all(c["passed"] for k, c in checks.items() if k not in ("robustness", "gate"))
    if solver_status == "inaccurate":
        return SOLVER_INACCURATE, None
    if not verified:
        return FAILED, None
    if checks["robustness"]["passed"] and np.isfinite(gamma):
        reason = NOT_CALIBRATED if premise_holds else NOT_CALIBRATED + "; " + PREMISE_VIOLATED
        return RELAXED, reason
    return UNCERTIFIED, None


def _unread_gain(taps: Taps, shape: sls.Shape) -> float:
    """Largest ``|Phi_uy|`` entry on the error channels the controller must not read (0 for
    ``measure: full``): position-only output feedback is checked on the taps, not assumed."""
    unread = [j for j in range(taps.Phi_uy.shape[2]) if j not in measured_channels(shape.measure)]
    return float(np.abs(taps.Phi_uy[:, :, unread]).max()) if unread else 0.0
