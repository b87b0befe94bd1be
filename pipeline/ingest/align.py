"""Frame alignment and the smoothing differentiator.

Alignment puts the VIO trajectory into the truth (motion-capture) frame:
``p_aligned = R p_vio + t``, chosen to minimize ``sum_i ||R p_vio_i + t - p_truth_i||^2``
over time-matched pairs.

- ``se3``: the full rigid transform, Umeyama's closed form without scale (Umeyama 1991;
  what ``evo_ape --align`` computes): with centred point sets ``a_i = p_vio_i - mean``,
  ``b_i = p_truth_i - mean`` and ``W = sum_i b_i a_i^T = U S V^T``,
  ``R = U diag(1, 1, det(U V^T)) V^T``, ``t = mean_truth - R mean_vio``.
- ``4dof``: a rotation about z only (yaw ``psi``) and a translation, the gauge freedom of
  visual-inertial odometry (gravity fixes roll and pitch):
  ``psi = atan2(sum (a_x b_y - a_y b_x), sum (a_x b_x + a_y b_y))`` over the centred
  points, ``t = mean_truth - R_z(psi) mean_vio``.
- ``none``: ``R = I``, ``t = 0``.

The smoothing differentiator (velocity from positions) is a Savitzky-Golay filter: a
least-squares quadratic fitted to a sliding window of ``window_s`` seconds (at least 5
samples), whose slope at the window's centre is the velocity. A quadratic fit
differentiates polynomials up to degree 3 exactly at the centre; white position noise of
standard deviation ``sigma`` gives velocity noise ``sigma sqrt(12 / (m (m^2 - 1))) / h``
(m samples, spacing h). Stamps that are not uniform (off the grid of their median spacing
by more than a millionth of it) are resampled linearly to that grid first; stretches
separated by gaps longer than ``max_gap`` are differentiated separately so that a gap
never smears into its neighbours.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from qsls.pipeline.core.rotations import rot_z
from qsls.pipeline.ingest.resample import interp_rows, median_spacing

METHODS = ("4dof", "se3", "none")
_ROWS = 1 << 16  # rows computed at once (bounded temporaries on long flights)


@dataclass(frozen=True)
class Alignment:
    """``p_aligned = rotation @ p + translation``."""

    method: str
    rotation: np.ndarray  # (3, 3)
    translation: np.ndarray  # (3,)

    @property
    def yaw_rad(self) -> float:
        return float(np.arctan2(self.rotation[1, 0], self.rotation[0, 0]))

    def apply(self, p: np.ndarray) -> np.ndarray:
        out = p @ self.rotation.T
        out += self.translation  # in place: the same sums, one array
        return out

    def rotate(self, v: np.ndarray) -> np.ndarray:
        return v @ self.rotation.T

    def as_dict(self) -> dict:
        return {
            "method": self.method,
            "rotation": self.rotation.tolist(),
            "translation": self.translation.tolist(),
            "yaw_rad": self.yaw_rad,
        }


def fit_alignment(
    src: np.ndarray, dst: np.ndarray, method: str, *, scratch_dst: bool = False
) -> Alignment:
    """The transform of ``method`` that maps ``src`` (VIO) best onto ``dst`` (truth);
    ``scratch_dst``: ``dst`` may be centred in place (the same values, no copy of it)."""
    src = np.asarray(src, dtype=float)
    dst = np.asarray(dst, dtype=float)
    if method == "none":
        return Alignment("none", np.eye(3), np.zeros(3))
    mu_s = src.mean(axis=0)
    mu_d = dst.mean(axis=0)
    if scratch_dst:
        dst -= mu_d
        r = best_rotation(src - mu_s, dst, method)
    else:
        r = best_rotation(src - mu_s, dst - mu_d, method)
    return Alignment(method, r, mu_d - r @ mu_s)


def best_rotation(a: np.ndarray, b: np.ndarray, method: str) -> np.ndarray:
    """The rotation ``R`` of ``method`` (``4dof`` or ``se3``) minimizing
    ``sum_i ||R a_i - b_i||^2`` over the centred point sets ``a``, ``b`` (module docstring),
    from their correlation ``M = sum_i a_i b_i^T``."""
    m = a.T @ b
    if method == "4dof":
        return rot_z(np.arctan2(m[0, 1] - m[1, 0], m[0, 0] + m[1, 1]))
    if method == "se3":
        u, _, vt = np.linalg.svd(m.T)
        d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt)) or 1.0])
        return u @ d @ vt
    raise ValueError(f"unknown alignment {method!r}; use one of {', '.join(METHODS)}")


def segments(t_ns: np.ndarray, max_gap_ns: int) -> list[slice]:
    """Index ranges of ``t_ns`` (sorted) split where consecutive stamps differ > max_gap."""
    cut = np.flatnonzero(np.diff(t_ns) > max_gap_ns) + 1
    edges = [0, *cut.tolist(), len(t_ns)]
    return [slice(a, b) for a, b in itertools.pairwise(edges) if b > a]


def savgol_derivative(
    x: np.ndarray, m: int, h: float, order: int = 2, out: np.ndarray | None = None
) -> np.ndarray:
    """First derivative of the rows of ``x`` (uniform step ``h``) by Savitzky-Golay smoothing:
    a least-squares polynomial of ``order`` over each window of ``m`` (odd) samples, its slope
    at the window's centre; the first and last ``m // 2`` samples take the slope of the
    polynomial fitted to the first/last window at their own position (scipy's
    ``savgol_filter(..., deriv=1, mode="interp")``, without importing scipy.signal).

    With the Vandermonde matrix ``V[i, j] = s_i^j`` of offsets ``s = -k..k`` (``k = m // 2``),
    the fit is ``c = pinv(V) x``, so the centre slope is the convolution with ``pinv(V)[1] / h``.
    The interior is computed on blocks of rows (each row's value is its own: the same as at
    once), written into ``out`` (a new array if None).
    """
    x = np.asarray(x, dtype=float)
    k = m // 2
    s = np.arange(-k, k + 1, dtype=float)
    pinv = np.linalg.pinv(np.vander(s, order + 1, increasing=True))  # (order+1, m)
    n = len(x)
    out = np.empty_like(x) if out is None else out
    # interior: out[i] = sum_j pinv[1, j] x[i - k + j]
    win = np.lib.stride_tricks.sliding_window_view(x, m, axis=0)  # (n - m + 1, cols, m)
    for a in range(0, len(win), _ROWS):
        out[k + a : k + min(a + _ROWS, len(win))] = win[a : a + _ROWS] @ pinv[1] / h
    # edges: slope d/ds sum_p c_p s^p = sum_p p c_p s^(p-1) at the edge samples' offsets
    powers = np.arange(1, order + 1)
    for rows, offsets in ((slice(0, m), s[:k]), (slice(n - m, n), s[k + 1 :])):
        c = pinv @ x[rows]  # (order+1, cols)
        d = (powers * offsets[:, None] ** (powers - 1)) @ c[1:]
        target = slice(0, k) if rows.start == 0 else slice(n - k, n)
        out[target] = d / h
    return out


def differentiate(
    t_ns: np.ndarray, p: np.ndarray, window_s: float = 0.1, max_gap_ns: int | None = None
) -> np.ndarray:
    """Velocity ``(n, 3)`` of positions ``p`` at sorted unique stamps ``t_ns`` (module doc)."""
    t_ns = np.asarray(t_ns, dtype=np.int64)
    p = np.asarray(p, dtype=float)
    out = np.zeros_like(p)
    parts = segments(t_ns, max_gap_ns) if max_gap_ns is not None else [slice(0, len(t_ns))]
    for sl in parts:
        t = (t_ns[sl] - t_ns[sl][0]) * 1e-9
        x = p[sl]
        n = len(t)
        if n < 2:
            continue
        h = median_spacing(t)
        m = max(5, round(window_s / h) | 1)
        grid_n = round(t[-1] / h) + 1
        if grid_n < m:
            out[sl] = np.gradient(x, t, axis=0) if n > 2 else (x[1] - x[0]) / (t[1] - t[0])
            continue
        tg = np.arange(grid_n) * h
        if grid_n == n and np.abs(t - tg).max() <= 1e-6 * h:
            savgol_derivative(x, m, h, out=out[sl])  # uniform already: no resampling
            continue
        vg = savgol_derivative(_interp_blocks(tg, t, x), m, h)
        _interp_blocks(t, tg, vg, out=out[sl])
    return out


def _interp_blocks(
    x: np.ndarray, xp: np.ndarray, fp: np.ndarray, out: np.ndarray | None = None
) -> np.ndarray:
    """``interp_rows(x, xp, fp)`` on blocks of ``x`` (each row's value is its own: the same
    as at once), into ``out`` (a new array if None): bounded temporaries."""
    out = np.empty((len(x), fp.shape[1])) if out is None else out
    for a in range(0, len(x), _ROWS):
        out[a : a + _ROWS] = interp_rows(x[a : a + _ROWS], xp, fp)
    return out
