"""Relative position error (RPE) against speed: does the VIO err more when flown faster?

On an aligned flight (``flight.parquet``: truth ``x`` and estimate ``y = x + e`` on one clock
and in one frame, after ingest's alignment), cut time into consecutive, non-overlapping
windows ``[t_i, t_i + W]`` (``W = 1 s`` by default) and, with ``p`` the true and ``q`` the
estimated position at the samples nearest the window's ends::

    RPE_i   = || (q(t_i + W) - q(t_i)) - (p(t_i + W) - p(t_i)) ||_2        (m, world frame)
    speed_i = (path length of p over the window) / W                      (m/s)

A window is kept when both ends have a sample within half a sampling period of the wanted
time (so gaps in the flight drop windows instead of stretching them). The statistic:

    ratio = mean(RPE over the fastest third of windows) / mean(RPE over the slowest third)
    rho   = Spearman rank correlation of (speed_i, RPE_i)

A constant error (a frame or bias offset) cancels in the difference, so RPE measures how
fast the error changes: drift, noise and outliers. This is the world-frame RPE (the flight
has no orientations); evo's ``evo_rpe`` expresses the same difference in the body frame of
the window's start, which adds the attitude error times the displacement.

No stage calls it: it is the measure behind ``benchmarks/bench_rpe.py`` and the camera
loop's RPE in ``benchmarks/bench_camera_euroc.py`` (docs/performance.md, docs/camera.md),
kept in the library so that both benchmarks and their tests share one definition.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class RpeSpeed:
    """The statistic of the module docstring on one flight."""

    windows: int
    ratio: float
    """Mean RPE of the fastest third of windows over that of the slowest third."""
    rho: float
    """Spearman rank correlation of window speed and RPE."""
    rpe_mean: float
    speed_mean: float


def rpe_windows(
    t: np.ndarray, p: np.ndarray, q: np.ndarray, window: float = 1.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(t_start, speed, rpe)`` per kept window, from times ``t`` (n,) in s, true positions
    ``p`` (n, 3) and estimated positions ``q`` (n, 3) (module docstring)."""
    t = np.asarray(t, dtype=float)
    p = np.asarray(p, dtype=float)[:, :3]
    q = np.asarray(q, dtype=float)[:, :3]
    if len(t) < 2 or window <= 0:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    tol = 0.5 * float(np.median(np.diff(t)))
    starts = t[0] + window * np.arange(int(np.floor((t[-1] - t[0]) / window + 1e-9)))
    i = _nearest(t, starts)
    k = _nearest(t, starts + window)
    keep = (np.abs(t[i] - starts) <= tol) & (np.abs(t[k] - starts - window) <= tol) & (k > i)
    i, k = i[keep], k[keep]
    path = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    speed = (path[k] - path[i]) / (t[k] - t[i])
    rpe = np.linalg.norm((q[k] - q[i]) - (p[k] - p[i]), axis=1)
    return t[i], speed, rpe


def _nearest(t: np.ndarray, want: np.ndarray) -> np.ndarray:
    """Index of the sample of sorted ``t`` nearest each ``want``."""
    j = np.clip(np.searchsorted(t, want), 1, len(t) - 1)
    return np.where(np.abs(t[j - 1] - want) <= np.abs(t[j] - want), j - 1, j)


def speed_statistic(speed: np.ndarray, rpe: np.ndarray) -> RpeSpeed:
    """``ratio`` and ``rho`` of the module docstring over windows (speed_i, RPE_i)."""
    from scipy.stats import spearmanr

    speed = np.asarray(speed, dtype=float)
    rpe = np.asarray(rpe, dtype=float)
    n = len(speed)
    if n < 3:
        raise ValueError(f"{n} windows: the RPE-vs-speed statistic needs at least 3")
    order = np.argsort(speed, kind="stable")
    third = n // 3
    slow = float(rpe[order[:third]].mean())
    fast = float(rpe[order[-third:]].mean())
    rho = float(spearmanr(speed, rpe)[0])
    ratio = fast / slow if slow > 0 else float("inf")
    return RpeSpeed(n, ratio, rho, float(rpe.mean()), float(speed.mean()))
