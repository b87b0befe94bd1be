"""An independent LQG reference for the synthesis tests (no qsls.pipeline.control.sls code).

LQR and Kalman gains from the discrete algebraic Riccati equations
(``scipy.linalg.solve_discrete_are``), the closed loop of plant and LQG controller written
out as one state-space system, and its squared H2 norm from a discrete Lyapunov equation.

- ``strictly_proper=False``: current-estimate form, ``u[k] = -K xhat[k|k]`` (uses ``y[k]``),
  the H2-optimal controller when ``Phi_uy(0)`` is free;
- ``strictly_proper=True``: predictor form, ``u[k] = -K xhat[k|k-1]``.

Noise: ``w = eps_w * w~`` entering through ``H``, ``e = eps_e * e~`` with white unit ``w~, e~``;
cost output ``[Q^1/2 x; R^1/2 u]``. The squared H2 norm is the steady-state
``E[x'Qx + u'Ru]``, the same number as the SLS H2 cost squared.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import solve_discrete_are, solve_discrete_lyapunov, sqrtm


def lqg_h2_squared(
    A: np.ndarray,
    B: np.ndarray,
    C: np.ndarray,
    H: np.ndarray,
    Q: np.ndarray,
    R: np.ndarray,
    eps_w: float,
    eps_e: float,
    *,
    strictly_proper: bool,
) -> float:
    nx, ny = A.shape[0], C.shape[0]
    W = eps_w**2 * H @ H.T
    V = eps_e**2 * np.eye(ny)
    P = solve_discrete_are(A, B, Q, R)
    K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)  # u = -K xhat
    Sig = solve_discrete_are(A.T, C.T, W, V)  # predictor error covariance
    G = np.linalg.inv(C @ Sig @ C.T + V)
    Lc = Sig @ C.T @ G  # measurement update (current estimate)
    Lp = A @ Sig @ C.T @ G  # predictor gain
    qh, rh = np.real(sqrtm(Q)), np.real(sqrtm(R))
    eye = np.eye(nx)
    Z = np.zeros
    if strictly_proper:
        Acl = np.block([[A, -B @ K], [Lp @ C, A - B @ K - Lp @ C]])
        Bcl = np.block([[H * eps_w, Z((nx, ny))], [Z((nx, H.shape[1])), Lp * eps_e]])
        Ccl = np.block([[qh, Z((nx, nx))], [Z((rh.shape[0], nx)), -rh @ K]])
        Dcl = Z((Ccl.shape[0], Bcl.shape[1]))
    else:
        F = A - B @ K
        Acl = np.block(
            [[A - B @ K @ Lc @ C, -B @ K @ (eye - Lc @ C)], [F @ Lc @ C, F @ (eye - Lc @ C)]]
        )
        Bcl = np.block([[H * eps_w, -B @ K @ Lc * eps_e], [Z((nx, H.shape[1])), F @ Lc * eps_e]])
        Ccl = np.block([[qh, Z((nx, nx))], [-rh @ K @ Lc @ C, -rh @ K @ (eye - Lc @ C)]])
        Dcl = np.block(
            [
                [Z((nx, H.shape[1])), Z((nx, ny))],
                [Z((rh.shape[0], H.shape[1])), -rh @ K @ Lc * eps_e],
            ]
        )
    assert np.abs(np.linalg.eigvals(Acl)).max() < 1.0
    X = solve_discrete_lyapunov(Acl, Bcl @ Bcl.T)
    return float(np.trace(Ccl @ X @ Ccl.T) + np.trace(Dcl @ Dcl.T))
