"""The realized disturbance ``w`` of a flight through the model (docs/guarantee.md, Premise).

With the linear model ``x_{k+1} = A x_k + B u_k + w_k`` (``H = I``), whatever the model does not
explain, mismatch included, is disturbance::

    w_k = x_{k+1} - A x_k - B (u_k - u_hover)

When the flight logged its inputs, this is measured directly. When it did not (a recorded
log of another vehicle, EuRoC), the input is unknown and only the part of ``w`` that *no*
input explains can be measured: per axis, with ``r1 = p_{k+1} - p_k - dt v_k``,
``r2 = v_{k+1} - v_k`` and the input entering as an acceleration ``a`` through
``(dt^2/2, dt)``, ``min_a max(|r1 - dt^2/2 a|, |r2 - dt a|) = |r1 dt - r2 dt^2/2| / (dt + dt^2/2)``.
That input-free residual is a lower bound on the realized ``w`` of any controller, and a
certificate built on it says so.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qsls.pipeline.core.plant import NX

Source = str
INPUTS = "inputs"
"""``w`` measured with the flight's logged inputs."""
RESIDUAL = "input_free_residual"
"""``w`` as the smallest disturbance that explains the motion under any input (a lower bound)."""


def input_states(A: np.ndarray, B: np.ndarray, du: np.ndarray) -> np.ndarray:
    """The model's extra states ``a_k`` (``(n, nx - NX)``) driven by the input deviations ``du``
    ``(n, nu)`` from rest: ``a_{k+1} = A_aa a_k + B_a du_k`` (they do not depend on the
    physical states). Empty for the hover plant."""
    du = np.nan_to_num(np.asarray(du, dtype=float))  # an unlogged step: no command change
    na = A.shape[0] - NX
    out = np.zeros((len(du), na))
    if na == 0:
        return out
    a_aa, b_a = A[NX:, NX:], B[NX:]
    a = np.zeros(na)
    for k in range(len(du)):
        out[k] = a
        a = a_aa @ a + b_a @ du[k]
    return out


def realized_disturbance(
    x: np.ndarray, u: np.ndarray, A: np.ndarray, B: np.ndarray, u_hover: np.ndarray
) -> np.ndarray:
    """``w_k = x_{k+1} - A x_k - B (u_k - u_hover)``, ``(n - 1, 6)`` for ``n`` samples.

    For the attitude plant (``A`` larger than the states ``x``) the model's extra states come
    from the inputs alone (:func:`input_states`), and ``w`` is what
    the model leaves unexplained on the physical states: ``w_k = x_{k+1} - [A z_k + B du_k]_x``
    with ``z_k = [x_k, a_k]``."""
    x = np.asarray(x, float)
    du = np.asarray(u, float) - np.asarray(u_hover, float)
    n = x.shape[1]
    if A.shape[0] == n:
        return x[1:] - x[:-1] @ A.T - du[:-1] @ B.T
    z = np.hstack([x, input_states(A, B, du)])
    return x[1:] - (z[:-1] @ A.T + du[:-1] @ B.T)[:, :n]


def deviation_disturbance(
    x: np.ndarray,
    u: np.ndarray,
    ref: np.ndarray,
    uff: np.ndarray,
    A: np.ndarray,
    B: np.ndarray,
    u_hover: np.ndarray,
) -> np.ndarray:
    """The proof's disturbance ``delta_k = dx_{k+1} - A dx_k - B du_k`` with ``dx = x - r`` and
    ``du = u - u_hover - uff`` (docs/guarantee.md, Disturbance in deviation coordinates),
    ``(n - 1, 6)``.

    It is what ``x - r = Phi_xx H delta + Phi_xy e`` is driven by: the absolute
    :func:`realized_disturbance` minus the reference's own residual
    ``r_{k+1} - A r_k - B uff_k``. The attitude plant's loop states are the model's response
    to the deviation inputs ``du`` from rest at the first tick."""
    return realized_disturbance(
        np.asarray(x, float) - np.asarray(ref, float),
        np.asarray(u, float) - np.asarray(uff, float),
        A,
        B,
        u_hover,
    )


def input_free_residual(x: np.ndarray, dt: float) -> np.ndarray:
    """The smallest ``w_k`` (per axis, infinity norm) that explains ``x_{k+1}`` from ``x_k``
    under any acceleration held over the step (module docstring); ``(n - 1, 6)``."""
    x = np.asarray(x, float)
    c1, c2 = 0.5 * dt * dt, dt
    r1 = x[1:, :3] - x[:-1, :3] - dt * x[:-1, 3:]
    r2 = x[1:, 3:] - x[:-1, 3:]
    a = (r1 + r2) / (c1 + c2)
    return np.hstack([r1 - c1 * a, r2 - c2 * a])


def step_inputs(t: np.ndarray, t_log: np.ndarray, u_log: np.ndarray, dt: float) -> np.ndarray:
    """The input held over each step ``[t_k, t_k + dt)``: the mean of the logged inputs in it
    (a controller faster than ``dt`` changes its command within the step); NaN where none."""
    t = np.asarray(t, float)
    t_log = np.asarray(t_log, float)
    u_log = np.asarray(u_log, float)
    order = np.argsort(t_log, kind="stable")
    t_log, u_log = t_log[order], u_log[order]
    tol = 1e-6 * dt
    lo = np.searchsorted(t_log, t - tol, side="left")
    hi = np.searchsorted(t_log, t + dt - tol, side="left")
    c = np.vstack([np.zeros((1, u_log.shape[1])), np.cumsum(u_log, axis=0)])
    n = (hi - lo)[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, (c[hi] - c[lo]) / np.maximum(n, 1), np.nan)


def flight_disturbance(
    t: np.ndarray,
    x: np.ndarray,
    dt: float,
    A: np.ndarray,
    B: np.ndarray,
    u_hover: np.ndarray,
    inputs: tuple[np.ndarray, np.ndarray] | None,
) -> np.ndarray:
    """``w_k`` per sample of one flight, ``(n, 6)`` (NaN at its last sample, across a gap and
    where the inputs do not cover the step): realized with ``inputs = (t_log, u_log)``, else
    the input-free residual."""
    t = np.asarray(t, float)
    out = np.full((len(t), 6), np.nan)
    if len(t) < 2:
        return out
    if inputs is not None:
        u = step_inputs(t, inputs[0], inputs[1], dt)
        w = realized_disturbance(x, u, A, B, u_hover)
    else:
        w = input_free_residual(x, dt)
    regular = np.abs(np.diff(t) - dt) <= 1e-6 * dt
    out[:-1] = np.where(regular[:, None], w, np.nan)
    return out


def shaped_norm(w: np.ndarray, H: np.ndarray | None) -> np.ndarray:
    """``||H^-1 w_k||_inf`` per row (``H = I`` when None): the disturbance in the model's
    ``x_{k+1} = A x_k + B u_k + H w_k`` (docs/guarantee.md; ``H`` square and invertible)."""
    w = np.asarray(w, float)
    if H is not None:
        w = np.linalg.solve(np.asarray(H, float), w.T).T
    return np.abs(w).max(axis=1)


@dataclass(frozen=True)
class BiasSplit:
    """A flight's disturbance split as the bias term's premise reads it
    (docs/guarantee.md#the-bias-term): ``w_k = D_w beta + w'_k``, one constant acceleration
    ``beta`` for the whole flight."""

    beta: np.ndarray
    """``beta`` (m/s^2 per axis) of the smallest ``ratio``."""
    residual: np.ndarray
    """``||w'_k||_inf = ||w_k - D_w beta||_inf`` per tick."""
    ratio: float
    """``min_beta max(||beta||_inf / eps_b, max_k ||w_k - D_w beta||_inf / eps_w)``: the
    smallest inflation of ``(eps_w, eps_b)`` under which the flight's disturbance holds."""


def split_bias(w: np.ndarray, dirs: np.ndarray, eps_w: float, eps_b: float) -> BiasSplit:
    """:class:`BiasSplit` of the disturbance ``w`` ((n, k), in the premise's coordinates
    ``H^-1 delta``) with bias directions ``dirs`` ((k, 3), ``H^-1 D``). The ratio is a linear
    program in ``(beta, t)``: minimize ``t`` subject to ``|beta_c| <= eps_b t`` and
    ``|w_kj - (dirs beta)_j| <= eps_w t``, which needs only each channel's largest and smallest
    ``w_kj``. Without a bias term (``eps_b = 0``) ``beta = 0`` and the ratio is
    ``max ||w_k|| / eps_w``."""
    w = np.asarray(w, dtype=float)
    k = dirs.shape[1]
    if eps_b <= 0 or not len(w) or not np.isfinite(w).any():
        res = np.abs(w).max(axis=1) if w.size else np.zeros(len(w))
        return BiasSplit(np.zeros(k), res, ratio(float(np.nanmax(res, initial=0.0)), eps_w))
    from scipy.optimize import linprog  # deferred: scipy.optimize is slow to import

    hi, lo = np.nanmax(w, axis=0), np.nanmin(w, axis=0)
    d = np.asarray(dirs, dtype=float)
    ones = np.ones((len(d), 1))
    eye = np.eye(k)
    # rows: w_hi - d beta <= eps_w t; d beta - w_lo <= eps_w t; +-beta <= eps_b t
    a_ub = np.vstack([
        np.hstack([-d, -eps_w * ones]), np.hstack([d, -eps_w * ones]),
        np.hstack([eye, -eps_b * np.ones((k, 1))]), np.hstack([-eye, -eps_b * np.ones((k, 1))]),
    ])  # fmt: skip
    b_ub = np.concatenate([-hi, lo, np.zeros(2 * k)])
    cost = np.zeros(k + 1)
    cost[-1] = 1.0
    sol = linprog(cost, A_ub=a_ub, b_ub=b_ub, bounds=[(None, None)] * (k + 1), method="highs")
    beta = np.asarray(sol.x[:k], dtype=float) if sol.status == 0 else np.zeros(k)
    res = np.abs(w - beta @ d.T).max(axis=1)
    worst = float(np.nanmax(res, initial=0.0))
    return BiasSplit(beta, res, max(ratio(float(np.abs(beta).max()), eps_b), ratio(worst, eps_w)))


def ratio(value: float, limit: float) -> float:
    """``value / limit`` with ``0 / 0 = 0`` and ``v / 0 = inf`` for ``v > 0``: a measured
    quantity over its premise bound (a score's part, docs/calibration.md)."""
    if value <= 0.0:
        return 0.0
    return value / limit if limit > 0.0 else float("inf")
