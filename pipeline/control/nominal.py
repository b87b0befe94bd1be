"""The PD controller's closed-loop responses, truncated to ``T`` taps (the imitation target).

With ``u = K y`` (:func:`qsls.pipeline.control.pdgain.pd_gain`, paper input convention), ``y = C x + e``
and ``x[k+1] = A x + B u + H w``, the closed loop is ``x[k+1] = A_cl x + B K e + H w`` with
``A_cl = A + B K C``, so (``k >= 1``)::

    Phi_xx(k) = A_cl^(k-1),          Phi_xy(k) = A_cl^(k-1) B K,
    Phi_ux(k) = K C A_cl^(k-1),      Phi_uy(k) = K C A_cl^(k-1) B K,   Phi_uy(0) = K,

and tap 0 of the other three is zero. Truncating the (infinite) responses after tap ``T``
leaves a FIR residual ``A_cl^T`` in the achievability equations: small for a well-damped
PD, reported in the PD's certificate as ``truncation_residual``.

The truncated responses underestimate the closed loop's norms (T = 20, the paper's PD:
``||Phi_xy||`` 3.28 truncated, 3.43 true), so a reference controller's certificate states the
true ones (:func:`closed_loop_norm`): the induced inf-to-inf norm of the whole impulse response
``G_0 + sum_{k>=1} L A_cl^(k-1) R z^-k``, summed to a horizon ``N`` and bounded above by a
geometric tail. With ``q = ||A_cl^m||_inf < 1`` for some ``m`` (one exists when the spectral
radius is below 1), ``L A_cl^(N+j+im) R = (L A_cl^(N+j)) (A_cl^m)^i R``, so

    sum_{k>N} ||L A_cl^(k-1) R||_inf <= ||R||_inf / (1 - q) * sum_{j<m} ||L A_cl^(N+j)||_inf,

and the norm lies in ``[lower, lower + tail]`` with ``lower`` the first ``N`` taps' norm.
"""

from __future__ import annotations

import math

import numpy as np
from pydantic import BaseModel, ConfigDict

from qsls.pipeline.control.pdgain import PDGains, pd_gain
from qsls.pipeline.control.sls import Taps
from qsls.pipeline.core.plant import LinearModel


def static_gain_responses(model: LinearModel, K: np.ndarray, T: int) -> Taps:
    """Closed-loop responses of ``u = K y`` on ``model``, taps ``0..T``."""
    a, b, c = model.A, model.B, model.C
    nx, nu, ny = model.nx, model.nu, model.ny
    acl = a + b @ K @ c
    xx = np.zeros((T + 1, nx, nx))
    p = np.eye(nx)
    for k in range(1, T + 1):
        xx[k] = p
        p = acl @ p
    ux = np.zeros((T + 1, nu, nx))
    xy = np.zeros((T + 1, nx, ny))
    uy = np.zeros((T + 1, nu, ny))
    ux[1:] = K @ c @ xx[1:]
    xy[1:] = xx[1:] @ b @ K
    uy[0] = K
    uy[1:] = K @ c @ xy[1:]
    return Taps(Phi_xx=xx, Phi_ux=ux, Phi_xy=xy, Phi_uy=uy)


def pd_responses(model: LinearModel, gains: PDGains, T: int) -> tuple[np.ndarray, Taps]:
    """``(K, taps)`` of the PD controller with ``gains`` on ``model``."""
    K = model_gain(pd_gain(gains, model.mass), model.ny)
    return K, static_gain_responses(model, K, T)


def model_gain(K: np.ndarray, ny: int) -> np.ndarray:
    """``K`` on the first measurement channels of an ``ny``-channel model, 0 on the others
    (the attitude plant's extra states: the PD does not read them)."""
    out = np.zeros((K.shape[0], ny))
    out[:, : K.shape[1]] = K
    return out


def spectral_radius(model: LinearModel, K: np.ndarray) -> float:
    """Largest closed-loop eigenvalue magnitude of ``A + B K C`` (< 1: stable)."""
    return float(np.abs(np.linalg.eigvals(model.A + model.B @ K @ model.C)).max())


# --------------------------------------------------------------------------- true norms
class ClosedLoopNorm(BaseModel):
    """A reference controller's infinite-horizon norm (module doc): ``value = lower + tail``
    (an upper bound), ``lower`` over taps ``0..horizon``, ``truncated`` over ``0..T``."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    value: float
    lower: float
    tail_bound: float
    horizon: int
    truncated: float


def _contraction(acl: np.ndarray, target: float = 0.5, max_power: int = 4096) -> tuple[int, float]:
    """The smallest ``m`` with ``q = ||A_cl^m||_inf <= target`` (else the best up to
    ``max_power`` below 1; ``(0, inf)`` when none)."""
    p = np.eye(len(acl))
    best = (0, math.inf)
    for m in range(1, max_power + 1):
        p = p @ acl
        q = float(np.abs(p).sum(axis=1).max())
        if q < 1.0 and q < best[1]:
            best = (m, q)
        if q <= target:
            return m, q
    return best


def closed_loop_norm(
    acl: np.ndarray,
    left: np.ndarray,
    right: np.ndarray,
    T: int,
    *,
    tap0: np.ndarray | None = None,
    rtol: float = 1e-12,
    max_horizon: int = 200_000,
) -> ClosedLoopNorm:
    """The induced inf-to-inf norm of ``tap0 + sum_{k>=1} left A_cl^(k-1) right z^-k``
    (module doc); ``inf`` when ``A_cl`` has no contracting power (not stable)."""
    rows = np.abs(tap0).sum(axis=1) if tap0 is not None else np.zeros(len(left))
    m, q = _contraction(acl)
    lp = np.asarray(left, dtype=float)  # left A_cl^(k-1)
    r_norm = float(np.abs(right).sum(axis=1).max())
    truncated = math.nan
    k = 0
    while True:
        k += 1
        rows = rows + np.abs(lp @ right).sum(axis=1)
        lp = lp @ acl
        if k == T:
            truncated = float(rows.max())
        if k >= T and (k % 64 == 0 or k == T):
            if m == 0:
                return ClosedLoopNorm(
                    value=math.inf, lower=float(rows.max()), tail_bound=math.inf,
                    horizon=k, truncated=truncated,
                )  # fmt: skip
            ahead, tail = lp, 0.0
            for _ in range(m):
                tail += float(np.abs(ahead).sum(axis=1).max())
                ahead = ahead @ acl
            tail *= r_norm / (1.0 - q)
            lower = float(rows.max())
            if tail <= rtol * max(lower, 1.0) or k >= max_horizon:
                return ClosedLoopNorm(
                    value=lower + tail, lower=lower, tail_bound=tail, horizon=k,
                    truncated=truncated,
                )  # fmt: skip


def static_gain_norms(model: LinearModel, K: np.ndarray, T: int) -> dict[str, ClosedLoopNorm]:
    """The true norms of ``u = K y``'s closed loop (module doc): ``phi_xx_h`` (``Phi_xx H``),
    ``phi_xy``, ``phi_ux`` (``Phi_ux H``), ``phi_uy``; ``truncated`` equals
    :func:`qsls.pipeline.control.sls.l1_norm` of :func:`static_gain_responses` at ``T``."""
    a, b, c, h = model.A, model.B, model.C, model.H
    acl = a + b @ K @ c
    nx = model.nx
    eye = np.eye(nx)
    return {
        "phi_xx_h": closed_loop_norm(acl, eye, h, T),
        "phi_xy": closed_loop_norm(acl, eye, b @ K, T),
        "phi_ux": closed_loop_norm(acl, K @ c, h, T),
        "phi_uy": closed_loop_norm(acl, K @ c, b @ K, T, tap0=K),
    }
