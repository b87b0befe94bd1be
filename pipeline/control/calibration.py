"""The calibrated premise on fixed taps (docs/calibration.md): ``P(lambda)`` and its condition.

A candidate controller has fixed taps and a nominal premise ``P = (eps, S, eps_w, Delta, m)``
fitted on design flights. Its calibration (:mod:`qsls.pipeline.calibrate.core`) finds an
inflation ``lambda_hat`` from the scores of flights the design never saw; here is what that
inflation does to the premise and to the guarantee:

    P(lambda) = (lambda eps, lambda S, lambda eps_w, lambda eps_b, lambda Delta, floor(lambda m))

(the outlier magnitude is bounded by the gate, ``eps_o = 2V - beta``, and is not inflated).
The certificate holds iff the fixed taps meet the robustness condition under ``P(lambda_hat)``
(:func:`qsls.pipeline.control.guarantee.guarantee` with ``G_m`` recomputed for the inflated
``m``, and the gate's ``rho_v <= V``). The tolerance of each premise quantity is the factor by
which it alone could grow before that condition fails. The quantile itself is
:mod:`qsls.pipeline.control.conformal`'s.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from qsls.pipeline.control.guarantee import (
    Guarantee,
    Norms,
    guarantee,
    sparse_gain,
    velocity_deviation,
)
from qsls.pipeline.premise.numbers import PremiseNumbers


# --------------------------------------------------------------------------- the condition
@dataclass(frozen=True)
class Responses:
    """What the condition needs of a controller's responses (``Phi_xy`` and ``Phi_xx H``)."""

    phi_xy: np.ndarray
    phi_xx_h: np.ndarray
    state_scale: tuple[float, ...]
    error_scale: tuple[float, ...]
    measured: tuple[int, ...]
    outlier: tuple[int, ...]
    norms: Norms
    """``N``, ``N_w``, ``G_b`` (``G_m`` is recomputed per ``m``)."""
    bias_dirs: np.ndarray | None = None
    """``D_w`` (:attr:`qsls.pipeline.core.plant.LinearModel.bias_dirs`), for the gate's
    ``g_b,i``."""


@dataclass(frozen=True)
class Check:
    """The robustness condition of a premise on fixed taps."""

    premise: PremiseNumbers
    guarantee: Guarantee
    G_m: float
    rho_v: float | None
    holds: bool


def inflate(p: PremiseNumbers, lam: float) -> PremiseNumbers:
    """``P(lambda)``: ``eps``, ``S``, ``eps_w``, ``eps_b``, ``Delta`` (and the paper's ``R0``, an
    error bound too) times ``lambda``, ``m -> floor(lambda m)``."""
    m = math.floor(lam * p.m + 1e-9) if math.isfinite(lam) else p.m
    R0 = None if p.R0 is None else p.R0 * lam
    return replace(
        p, eps=p.eps * lam, S=p.S * lam, eps_w=p.eps_w * lam, delta=p.delta * lam, m=m, R0=R0,
        eps_b=p.eps_b * lam,
    )  # fmt: skip


def check(p: PremiseNumbers, taps: Responses) -> Check:
    """The condition ``lhs <= 1``, ``rho* <= r`` and (with a gate) ``rho_v <= V`` under ``p``."""
    values = (p.eps, p.S, p.eps_w, p.delta)
    if not all(math.isfinite(v) for v in values):  # an infinite inflation: nothing holds
        inf = math.inf
        return Check(p, Guarantee(inf, -inf, inf, inf, inf, inf, inf), inf, None, False)
    gm = sparse_gain(taps.phi_xy, taps.state_scale, taps.outlier, p.m)
    norms = replace(taps.norms, G_m=gm)
    g = guarantee(p, norms)
    ok = g.robustness_lhs <= 1.0 and g.rho_star <= p.radius
    rho_v = None
    if p.gate is not None:
        rho_v = velocity_deviation(
            taps.phi_xy, taps.phi_xx_h, p, error_scale=taps.error_scale,
            measured=taps.measured, outlier_channels=taps.outlier, bias_dirs=taps.bias_dirs,
        )  # fmt: skip
        ok = ok and rho_v <= p.gate
    return Check(p, g, gm, rho_v, bool(ok))


Quantity = Literal["eps", "S", "eps_w", "delta", "m"]
QUANTITIES: tuple[Quantity, ...] = ("eps", "S", "eps_w", "delta", "m")


def tolerance(p: PremiseNumbers, taps: Responses, quantity: Quantity) -> float:
    """The factor by which ``quantity`` alone could grow before the condition fails (1 or less:
    it fails already; inf: it never fails from this quantity). ``m`` counts whole outliers:
    the largest ``m' / m`` that still holds (``m' >= m``); with ``m = 0``, ``m' + 1``."""
    base = check(p, taps)
    if not base.holds:
        return 0.0
    if quantity == "m":
        m = p.m
        while m < 10_000 and check(replace(p, m=m + 1), taps).holds:
            m += 1
            if m >= taps.phi_xy.shape[0]:
                return math.inf  # every tap may carry an outlier
        return m / p.m if p.m > 0 else float(m + 1)
    value = float(getattr(p, quantity))
    if value == 0.0:
        return math.inf

    def holds(f: float) -> bool:
        return check(_with(p, quantity, value * f), taps).holds

    return _largest(holds, 1.0)


def _with(p: PremiseNumbers, quantity: Quantity, value: float) -> PremiseNumbers:
    """``p`` with ``quantity`` (``eps``, ``S``, ``eps_w`` or ``delta``) set to ``value``."""
    g = {"eps": p.eps, "S": p.S, "eps_w": p.eps_w, "delta": p.delta} | {quantity: value}
    return replace(p, eps=g["eps"], S=g["S"], eps_w=g["eps_w"], delta=g["delta"])


def largest_value(p: PremiseNumbers, taps: Responses, quantity: Quantity) -> float:
    """The largest value ``quantity`` alone could take before the condition fails: what
    :func:`tolerance` cannot say of a quantity stated as 0 (its factor is inf, yet a small
    ``S`` may break the condition). 0 when the condition fails already."""
    if quantity == "m":
        raise ValueError("m counts whole outliers: tolerance() gives its largest count")
    if not check(p, taps).holds:
        return 0.0
    value = float(getattr(p, quantity))
    if value > 0.0:
        return value * tolerance(p, taps, quantity)

    def holds(v: float) -> bool:
        return check(_with(p, quantity, v), taps).holds

    lo = 1e-9
    return _largest(holds, lo) if holds(lo) else 0.0


def _largest(holds: Callable[[float], bool], lo: float) -> float:
    """The largest ``f >= lo`` with ``holds(f)`` (monotone: every quantity enters the condition
    with a non-negative coefficient), to 1e-6 relative."""
    hi = 2.0 * lo
    while holds(hi):
        lo, hi = hi, 2.0 * hi
        if hi > 1e12:
            return math.inf
    while hi - lo > 1e-6 * lo:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if holds(mid) else (lo, mid)
    return lo
