"""The checks behind every certificate (DESIGN.md, Robust synthesis; issue 5).

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
- guarantee: ``lhs = (S + eps_e/r)||Phi_xy|| + (eps_w ||Phi_xx H|| + Delta)/r < 1``, so
  ``gamma = (eps_e + S a) / (1 - S ||Phi_xy||)``, ``a = eps_w ||Phi_xx H|| + Delta``, and the
  paper's ``gamma_strict = R0 / (1 - S ||Phi_xy||)`` are finite.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from qsls.pipeline.control import sls
from qsls.pipeline.control.plant import LinearModel
from qsls.pipeline.control.realize import FilterBank, RealizedController, filter_bank
from qsls.pipeline.control.sls import Taps

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


@dataclass(frozen=True)
class Setting:
    """The numbers a certificate is checked against."""

    S: float
    eps_e: float
    radius: float
    eps_w: float
    delta: float
    R0: float


def guarantee(norm_xy: float, norm_xx_h: float, s: Setting) -> dict[str, float]:
    """``robustness_lhs``, ``margin = 1 - lhs``, ``gamma`` and ``gamma_strict`` (inf when
    ``S ||Phi_xy|| >= 1``: no guarantee)."""
    lhs = sls.robustness_lhs(norm_xy, norm_xx_h, s.S, s.eps_e, s.radius, s.eps_w, s.delta)
    a = s.eps_w * norm_xx_h + s.delta
    den = 1.0 - s.S * norm_xy
    gamma = (s.eps_e + s.S * a) / den if den > 0 else float("inf")
    strict = s.R0 / den if den > 0 else float("inf")
    return {
        "robustness_lhs": float(lhs),
        "margin": float(1.0 - lhs),
        "s_times_norm_phi_xy": float(s.S * norm_xy),
        "a": float(a),
        "gamma": float(gamma),
        "gamma_strict": float(strict),
    }


def certify(
    taps: Taps,
    model: LinearModel,
    setting: Setting,
    *,
    solver_status: str = "optimal",
    reference: bool = False,
    premise_holds: bool = True,
) -> tuple[str, dict[str, Any]]:
    """Run every check on ``taps``; returns ``(status, fields)``.

    ``status``: ``certified`` (all checks passed, ``lhs < 1`` and the premise holds on all
    the training data), ``certified_relaxed`` (the same, but ``premise_holds`` is False: part
    of the training data violates the premise, :mod:`qsls.pipeline.control.premise`), ``uncertified`` (the
    controller is realized and verified but the robustness condition fails, so there is no
    guarantee), ``solver_inaccurate`` / ``failed`` (never certified), or ``reference`` for
    a controller that was not synthesized (the PD, whose truncated responses are stored).
    """
    bank = filter_bank(taps)
    residuals = sls.achievability_residuals(taps, model)
    resid = max(residuals.values())
    n_xy = sls.l1_norm(taps.Phi_xy)
    n_xx = sls.l1_norm(taps.Phi_xx, model.H)
    g = guarantee(n_xy, n_xx, setting)
    fields: dict[str, Any] = {
        "norm_phi_xx_h": n_xx,  # ||Phi_xx H|| (H = I by default)
        "norm_phi_xy": n_xy,
        "norm_phi_ux": sls.l1_norm(taps.Phi_ux, model.H),
        "norm_phi_uy": sls.l1_norm(taps.Phi_uy),
        **g,
        "achievability_residual": resid,
    }
    if reference:
        fields["truncation_residual"] = resid
        return "reference", fields
    rerr = realization_error(taps, model, bank)
    peak, final = perturbation_response(model, bank)
    fields["realization_error"] = rerr
    fields["perturbation_peak"] = peak
    fields["perturbation_final"] = final
    checks: dict[str, dict[str, Any]] = {
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
        "robustness": {
            "value": g["robustness_lhs"],
            "limit": 1.0,
            "passed": g["robustness_lhs"] < 1.0,
        },
    }
    fields["checks"] = checks
    verified = all(c["passed"] for k, c in checks.items() if k != "robustness")
    if solver_status == "inaccurate":
        status = "solver_inaccurate"
    elif not verified:
        status = "failed"
    elif checks["robustness"]["passed"] and np.isfinite(g["gamma"]):
        status = "certified" if premise_holds else "certified_relaxed"
    else:
        status = "uncertified"
    return status, fields
