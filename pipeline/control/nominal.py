"""The PD controller's closed-loop responses, truncated to ``T`` taps (the imitation target).

With ``u = K y`` (:func:`qsls.pipeline.control.pdgain.pd_gain`, paper input convention), ``y = C x + e``
and ``x[k+1] = A x + B u + H w``, the closed loop is ``x[k+1] = A_cl x + B K e + H w`` with
``A_cl = A + B K C``, so (``k >= 1``)::

    Phi_xx(k) = A_cl^(k-1),          Phi_xy(k) = A_cl^(k-1) B K,
    Phi_ux(k) = K C A_cl^(k-1),      Phi_uy(k) = K C A_cl^(k-1) B K,   Phi_uy(0) = K,

and tap 0 of the other three is zero. Truncating the (infinite) responses after tap ``T``
leaves a FIR residual ``A_cl^T`` in the achievability equations: small for a well-damped
PD, reported in the PD's certificate as ``truncation_residual``.
"""

from __future__ import annotations

import numpy as np

from qsls.pipeline.control.pdgain import PDGains, pd_gain
from qsls.pipeline.control.plant import LinearModel
from qsls.pipeline.control.sls import Taps


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
    K = pd_gain(gains, model.mass)
    return K, static_gain_responses(model, K, T)


def spectral_radius(model: LinearModel, K: np.ndarray) -> float:
    """Largest closed-loop eigenvalue magnitude of ``A + B K C`` (< 1: stable)."""
    return float(np.abs(np.linalg.eigvals(model.A + model.B @ K @ model.C)).max())
