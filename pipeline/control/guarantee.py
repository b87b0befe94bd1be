"""The guarantee's arithmetic, in one place (docs/guarantee.md).

Norms are weighted: ``|z|_x = ||W_x z||_inf`` on states, ``|e|_e = ||W_e e||_inf`` on errors;
``dist(x) = min_d |x - x_d|_x`` to the training states. The premise (dense plus sparse errors,
:mod:`qsls.pipeline.premise.honest`) is ``|d_k|_e <= eps + S dist(x_k)`` within ``r``, at most
``m`` outliers ``||o_k||_inf <= eps_o`` in any ``T`` consecutive steps, ``w_k = D_w beta + w'_k``
with a constant acceleration bias ``||beta||_inf <= eps_b`` and ``||w'_k||_inf <= eps_w``, and
``dist(x_ref,k) <= Delta``. The system quantities of responses ``Phi``::

    N   = ||W_x Phi_xy W_e^-1||                     (measured error channels only)
    N_w = ||W_x Phi_xx H||
    G_m = max_i w_x,i * (sum of the m largest over taps t of sum_{j outlier} |Phi_xy(t)_ij|)
    G_b = max_i w_x,i max_K sum_c |P_K|_ic          P_K = sum_{t<=K} Phi_xx(t) H D_w
    a   = eps_w N_w + eps_b G_b + Delta

(``G_b``: the peak response to a constant bias, docs/guarantee.md#the-bias-term; with integral
action, ``P_T = 0`` on the physical states, it decays to 0 after ``T`` ticks.)

Robustness condition and conclusion::

    lhs  = (S + eps/r) N + (a + eps_o G_m) / r <= 1 - margin
    rho* = (a + N eps + eps_o G_m) / (1 - S N) <= r        (dist(x_k) <= rho* for all k)
    |d_k|_e <= eps + S rho*                                  (the dense error stays bounded)

With ``W_x = W_e = I`` and no outliers (``m = 0``) this is Dean et al.'s theorem:
``eps + S rho* = (eps + S a) / (1 - S N) = gamma``. The paper's stricter comparison
``gamma_strict = R0 / (1 - S N)`` drops ``a``. The condition ``(S + eps/r) N_lower < 1`` is
necessary because ``N >= N_lower = max_i w_x,i / w_e,i`` over the positions on this plant
(:func:`min_norm_bound`; with unit weights ``S + eps/r < 1``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from qsls.pipeline.control.taps import l1_norm
from qsls.pipeline.core.plant import VELOCITY, measured_channels
from qsls.pipeline.premise.numbers import PremiseNumbers

ONES = (1.0,) * 6
# re-exported: one definition each, the channels in the plant, the numbers in the premise
__all__ = ["VELOCITY", "PremiseNumbers", "measured_channels"]


def outlier_channels(measure: str, m: int) -> tuple[int, ...]:
    """Channels whose errors may hold outliers: the measured velocities when ``m > 0``."""
    return VELOCITY if measure == "full" and m > 0 else ()


def error_weights(error_scale: Sequence[float], measured: Sequence[int]) -> np.ndarray:
    """``W_e^-1`` on the measured channels, 0 on the others (their columns of ``Phi_xy`` vanish)."""
    inv = np.zeros(len(error_scale))
    for j in measured:
        inv[j] = 1.0 / float(error_scale[j])
    return inv


def sparse_gain(
    phi_xy: np.ndarray, state_scale: Sequence[float], channels: Sequence[int], m: int
) -> float:
    """``G_m``: the peak gain of ``Phi_xy`` for inputs with at most ``m`` nonzero taps, each of
    infinity norm at most 1, on ``channels``."""
    if m <= 0 or not len(channels):
        return 0.0
    per_tap = np.abs(phi_xy[:, :, list(channels)]).sum(axis=2)  # (taps, nx)
    top = -np.sort(-per_tap, axis=0)[:m]  # the m largest taps of every row
    return float((np.asarray(state_scale, float) * top.sum(axis=0)).max())


def bias_rows(phi_xx_h: np.ndarray, bias_dirs: np.ndarray | None) -> np.ndarray:
    """``g_b,i = max_K sum_c |P_K|_ic`` per state row, ``P_K = sum_{t<=K} Phi_xx(t) H D_w``: the
    peak of row ``i``'s response to a constant bias ``||beta||_inf <= 1`` acting from the first
    tick (after tap ``T`` the response stays at ``P_T``). Zeros without bias directions."""
    nx = phi_xx_h.shape[1]
    if bias_dirs is None:
        return np.zeros(nx)
    partial = np.cumsum(phi_xx_h @ np.asarray(bias_dirs, float), axis=0)  # (taps, nx, 3)
    return np.asarray(np.abs(partial).sum(axis=2).max(axis=0), dtype=float)


def bias_gain(
    phi_xx_h: np.ndarray, bias_dirs: np.ndarray | None, state_scale: Sequence[float] = ONES
) -> float:
    """``G_b = max_i w_x,i g_b,i`` (:func:`bias_rows`)."""
    rows = bias_rows(phi_xx_h, bias_dirs)
    wx = np.zeros(len(rows))
    wx[: len(state_scale)] = np.asarray(state_scale, float)[: len(rows)]
    return float((wx * rows).max())


@dataclass(frozen=True)
class Norms:
    """The system quantities of one controller's responses."""

    N: float
    N_w: float
    G_m: float
    G_b: float = 0.0


def system_norms(
    phi_xy: np.ndarray,
    phi_xx_h: np.ndarray,
    *,
    state_scale: Sequence[float] = ONES,
    error_scale: Sequence[float] = ONES,
    measured: Sequence[int] = tuple(range(6)),
    outlier_channels: Sequence[int] = (),
    m: int = 0,
    bias_dirs: np.ndarray | None = None,
) -> Norms:
    """``N``, ``N_w``, ``G_m`` and ``G_b`` (module docstring) from the taps ``Phi_xy`` and
    ``Phi_xx H`` (``G_b`` 0 without ``bias_dirs``,
    :attr:`qsls.pipeline.core.plant.LinearModel.bias_dirs`)."""
    wx = np.asarray(state_scale, float)[None, :, None]
    inv_e = error_weights(error_scale, measured)[None, None, :]
    return Norms(
        N=l1_norm(wx * phi_xy * inv_e),
        N_w=l1_norm(wx * phi_xx_h),
        G_m=sparse_gain(phi_xy, state_scale, outlier_channels, m),
        G_b=bias_gain(phi_xx_h, bias_dirs, state_scale),
    )


def a_value(eps_w: float, N_w: float, delta: Any, eps_b: float = 0.0, G_b: float = 0.0) -> Any:
    """``a = eps_w N_w + eps_b G_b + Delta`` (``Delta`` a number, or measured distances: an
    array)."""
    return eps_w * N_w + eps_b * G_b + delta


def a_prior(p: PremiseNumbers, n: Norms) -> float:
    """``a = eps_w N_w + eps_b G_b + Delta``: the a-priori bound on ``dist(x_hat_k)``."""
    return a_value(p.eps_w, n.N_w, p.delta, p.eps_b, n.G_b)


def denominator(S: float, N: float) -> float:
    """``1 - S N``: the theorem's bounds are finite only while it is positive."""
    return 1.0 - S * N


def premise_bound(eps: float, S: float, distance: Any) -> Any:
    """``eps + S d``: the dense premise's bound at distance ``d`` (a number or an array)."""
    if isinstance(distance, int | float):
        return eps + S * distance
    return eps + S * np.asarray(distance, dtype=float)


def gamma_of(eps: float, S: float, N: float, a: Any) -> Any:
    """``gamma = (eps + S a) / (1 - S N)`` (inf when ``S N >= 1``): Dean et al.'s bound on
    ``|e|`` for an a-priori (or measured) ``a`` (a number or an array)."""
    den = denominator(S, N)
    a = np.asarray(a, dtype=float)
    out = np.full(a.shape, math.inf) if den <= 0 else (eps + S * a) / den
    return float(out) if out.ndim == 0 else out


def gamma_strict_of(R0: float, S: float, N: float) -> float:
    """``gamma_strict = R0 / (1 - S N)`` (inf when ``S N >= 1``): the paper's comparison."""
    den = denominator(S, N)
    return R0 / den if den > 0 else math.inf


def robustness_lhs(p: PremiseNumbers, n: Norms) -> float:
    """``(S + eps/r) N + (a + eps_o G_m) / r``."""
    return p.slope_ratio * n.N + (a_prior(p, n) + p.eps_o * n.G_m) / p.radius


def min_norm_bound(
    state_scale: Sequence[float] = ONES, error_scale: Sequence[float] = ONES
) -> float:
    """``N_lower = max over positions i of w_x,i / w_e,i <= N`` for every achievable response.

    The taps of ``Phi_xy`` sum to ``-I`` on the position channels (the achievability equations
    with the FIR end condition: a constant position error moves the position by its negative),
    so row ``i`` of ``W_x Phi_xy W_e^-1`` has an l1 sum of at least ``w_x,i / w_e,i``."""
    return max(float(state_scale[i]) / float(error_scale[i]) for i in range(3))


def necessary_condition(
    p: PremiseNumbers, state_scale: Sequence[float] = ONES, error_scale: Sequence[float] = ONES
) -> float:
    """``(S + eps/r) N_lower``: below 1 is necessary for feasibility, since the robustness
    condition needs ``(S + eps/r) N < 1`` and ``N >= N_lower`` (:func:`min_norm_bound`; 1 with
    unit weights, where it reads ``S + eps/r < 1``)."""
    return p.slope_ratio * min_norm_bound(state_scale, error_scale)


def largest_slope(n: Norms, p: PremiseNumbers, backoff: float = 0.0) -> float:
    """``rho = (1 - backoff - Delta/r - (eps_w N_w + eps_b G_b + eps_o G_m)/r) / N``: the
    largest ``S + eps/r`` the robustness condition leaves these responses under premise ``p``
    (its ``eps`` and ``S`` aside, so one ratio serves every ``eps``)."""
    rest = p.eps_w * n.N_w + p.eps_b * n.G_b + p.eps_o * n.G_m
    return (1.0 - backoff - p.delta / p.radius - rest / p.radius) / n.N


def rho_star(p: PremiseNumbers, n: Norms, a: float | None = None) -> float:
    """``(a + N eps + eps_o G_m) / (1 - S N)`` (inf when ``S N >= 1``); ``a`` defaults to the
    a-priori :func:`a_prior` (on a flight, the measured ``max dist(x_hat)``)."""
    den = denominator(p.S, n.N)
    if den <= 0:
        return math.inf
    a = a_prior(p, n) if a is None else a
    return (a + n.N * p.eps + p.eps_o * n.G_m) / den


def dense_bound(p: PremiseNumbers, rho: float) -> float:
    """``eps + S rho``: the bound on ``|d_k|_e`` while ``dist(x_k) <= rho``."""
    return premise_bound(p.eps, p.S, rho) if math.isfinite(rho) else math.inf


def velocity_deviation(
    phi_xy: np.ndarray,
    phi_xx_h: np.ndarray,
    p: PremiseNumbers,
    *,
    error_scale: Sequence[float] = ONES,
    measured: Sequence[int] = tuple(range(6)),
    outlier_channels: Sequence[int] = (),
    bias_dirs: np.ndarray | None = None,
) -> float:
    """``rho_v``: the bound on ``|v_k - v_ref,k|`` that the velocity gate needs (docs/guarantee.md,
    Velocity gate). With ``x - x_ref = Phi_xx H (D_w beta + w') + Phi_xy (d + o)``,
    ``|d_j| <= (eps + S r) / w_e,j`` while ``dist(x) <= rho* <= r``, per velocity row ``i``::

        rho_v = max_i eps_w sum|Phi_xx H|_i + eps_b g_b,i + (eps + S r) sum|Phi_xy W_e^-1|_i
                + eps_o G_m,i

    (unweighted rows: the gate is in m/s; ``g_b,i`` of :func:`bias_rows`)."""
    inv_e = error_weights(error_scale, measured)[None, None, :]
    g_b = bias_rows(phi_xx_h, bias_dirs)
    out = 0.0
    for i in VELOCITY:
        dense = float(np.abs(phi_xy[:, i, :] * inv_e[0]).sum())
        dist = float(np.abs(phi_xx_h[:, i, :]).sum())
        sparse = 0.0
        if p.m > 0 and len(outlier_channels):
            per_tap = np.abs(phi_xy[:, i, list(outlier_channels)]).sum(axis=1)
            sparse = float(np.sort(per_tap)[::-1][: p.m].sum())
        out = max(
            out,
            p.eps_w * dist
            + p.eps_b * float(g_b[i])
            + premise_bound(p.eps, p.S, p.radius) * dense
            + p.eps_o * sparse,
        )
    return out


@dataclass(frozen=True)
class Guarantee:
    """What a controller's certificate promises, with the numbers it follows from."""

    robustness_lhs: float
    margin: float
    a: float
    rho_star: float
    dense_bound: float
    """``eps + S rho*`` (Dean et al.'s gamma in the special case)."""
    gamma_strict: float
    s_times_n: float


def guarantee(p: PremiseNumbers, n: Norms) -> Guarantee:
    """Every number of the guarantee for premise ``p`` and system quantities ``n``."""
    lhs = robustness_lhs(p, n)
    rho = rho_star(p, n)
    r0 = p.eps if p.R0 is None else p.R0
    return Guarantee(
        robustness_lhs=float(lhs),
        margin=float(1.0 - lhs),
        a=float(a_prior(p, n)),
        rho_star=float(rho),
        dense_bound=float(dense_bound(p, rho)),
        gamma_strict=gamma_strict_of(r0, p.S, n.N),
        s_times_n=float(p.S * n.N),
    )


def error_bounds(
    dense: float, error_scale: Sequence[float], measured: Sequence[int], beta: float = math.inf
) -> np.ndarray:
    """``db_j``: the bound on the dense error of channel ``j`` under the premise,
    ``dense / w_e,j`` (``|d|_e <= dense``), at most ``beta`` on a velocity channel (where
    ``d = clip_beta(e)``); 0 on channels not measured."""
    db = dense * error_weights(error_scale, measured)
    for j in VELOCITY:
        if j in measured:
            db[j] = min(db[j], beta)
    return db


MONITOR_RTOL = 1e-9
"""The monitor's thresholds are widened by this share (plus ten times the certificate's
realization error per tap) for rounding: the closed loop of the realized controller
reproduces ``Phi`` to its ``realization_error`` (about 1e-13 on the quickstart)."""
