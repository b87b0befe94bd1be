"""The motion-dependent parts of the VIO emulator (equations: :mod:`qsls.pipeline.sim.vio`).

Arrays in, arrays out; the emulator owns the random streams and the state carried from one
call to the next (the drift sums and a feature-loss burst in progress).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def blur_pixels(
    x: np.ndarray, omega: np.ndarray, exposure_s: float, focal_px: float, min_height: float
) -> np.ndarray:
    """Blur ``b = t_exp f (||omega||_2 + ||v_xy||_2 / max(p_z, h_min))`` (px), per row of
    states ``x`` (n, 6) and body rates ``omega`` (n, 3) (rad/s)."""
    rot = np.sqrt((omega * omega).sum(axis=1))
    trans = np.sqrt((x[:, 3:5] * x[:, 3:5]).sum(axis=1)) / np.maximum(x[:, 2], min_height)
    return exposure_s * focal_px * (rot + trans)


def velocity_spikes(
    u: np.ndarray, hit: np.ndarray, lo: float, hi: float
) -> tuple[np.ndarray, np.ndarray]:
    """(rows, spikes (len(rows), 3)) for the rows where ``hit``: one velocity axis (from
    ``u[:, 1]``) gets a spike of sign and magnitude in ``[lo, hi]`` from ``u[:, 2]``
    (``[0, .5)`` negative, ``[.5, 1)`` positive)."""
    rows = np.nonzero(hit)[0]
    if not len(rows):  # the usual case: skip the arithmetic
        return rows, np.zeros((0, 3))
    axis = np.minimum((u[rows, 1] * 3).astype(int), 2)
    w = u[rows, 2]
    sign = np.where(w < 0.5, -1.0, 1.0)
    frac = np.where(w < 0.5, w * 2.0, (w - 0.5) * 2.0)
    out = np.zeros((len(rows), 3))
    out[np.arange(len(rows)), axis] = sign * (lo + frac * (hi - lo))
    return rows, out


@dataclass
class Burst:
    """A feature-loss burst in progress: ``left`` of ``length`` samples, peak ``amp`` (6,)."""

    length: int = 0
    left: int = 0
    amp: np.ndarray | None = None


def burst_errors(
    burst: Burst,
    start_prob: np.ndarray,
    u: np.ndarray,
    duration_samples: tuple[int, int],
    peak: np.ndarray,
) -> np.ndarray:
    """Feature-loss error (n, 6) of the next ``n`` samples; updates ``burst`` in place.

    A burst starts at sample ``k`` (when none is running) if ``u[k, 0] < start_prob[k]``; it
    lasts ``L`` samples, ``L`` uniform in ``duration_samples`` from ``u[k, 1]``, and adds
    ``amp sin(pi (j + 1) / (L + 1))`` at its ``j``-th sample (rise, peak, recovery), with
    ``amp = peak * (2 u[k, 2:8] - 1)``.
    """
    n = len(start_prob)
    out = np.zeros((n, 6))
    k = 0
    lo, hi = duration_samples
    while k < n:
        if burst.left == 0:
            cand = np.nonzero(u[k:, 0] < start_prob[k:])[0]
            if not len(cand):
                break
            k += int(cand[0])
            burst.length = lo + min(int(u[k, 1] * (hi - lo + 1)), hi - lo)
            burst.left = burst.length
            burst.amp = peak * (2.0 * u[k, 2:8] - 1.0)
        j0 = burst.length - burst.left
        m = min(burst.left, n - k)
        j = np.arange(j0, j0 + m)
        assert burst.amp is not None
        out[k : k + m] = np.sin(np.pi * (j + 1) / (burst.length + 1))[:, None] * burst.amp
        burst.left -= m
        k += m
    return out
