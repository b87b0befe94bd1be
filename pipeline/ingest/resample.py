"""The resampling grid ``t_k = t_0 + k dt`` and linear interpolation of sampled signals,
every column at once (docs/ingest.md#steps, step 6)."""

from __future__ import annotations

import numpy as np

from qsls.pipeline.core.errors import InputError

FINEST_GRID = 10
"""How much finer than the VIO's own sampling step ``dt`` may be (finer is interpolation only)."""


def time_grid(lo_ns: int, hi_ns: int, dt_ns: int) -> np.ndarray:
    """``t_k = t_0 + k dt`` (int64 ns) over ``[lo_ns, hi_ns]``, ``t_0`` the first multiple of
    ``dt_ns`` at or after ``lo_ns``: every stream resampled at ``dt`` lands on the same ticks."""
    start = -(-lo_ns // dt_ns) * dt_ns
    return np.arange(start, hi_ns + 1, dt_ns, dtype=np.int64)


def check_grid(dt: float, vio_t_ns: np.ndarray, span_ns: int) -> None:
    """Refuse a ``dt`` far finer than the VIO's own sampling: a flight of interpolated
    samples that carry no new information, and gigabytes of them (``--dt 1e-6`` on 100 Hz
    data: 2.7 GB)."""
    step_s = float(np.median(np.diff(vio_t_ns))) * 1e-9 if len(vio_t_ns) > 1 else 0.0
    if step_s > 0 and dt * FINEST_GRID < step_s:
        n = int(span_ns * 1e-9 / dt)
        raise InputError(
            f"--dt {dt:g} s is {step_s / dt:,.0f} times finer than the VIO's own sampling step "
            f"({step_s:.3g} s): {n:,} samples (about {n * 13 * 8 / 1e9:.3g} GB) of interpolation "
            f"only; choose --dt of at least {step_s / FINEST_GRID:.3g} s (the paper's: 0.1)"
        )


def interp_rows(x: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """The rows of ``fp`` (``(n, k)``, sampled at the increasing ``xp``) linearly interpolated
    at ``x``: ``fp[j] + w (fp[j+1] - fp[j])`` with ``xp[j] <= x < xp[j+1]`` and
    ``w = (x - xp[j]) / (xp[j+1] - xp[j])``, held at the end rows outside ``xp`` (what
    ``np.interp`` gives per column).

    One bracket search and one gather of rows serve all ``k`` columns; ``np.interp`` per
    column searches ``xp`` ``k`` times (the clock-offset search interpolates the truth's
    six columns some 80 times: 26 -> 8 ms).
    """
    return interp_rows_many(x, xp, [fp])[0]


def interp_rows_many(x: np.ndarray, xp: np.ndarray, fps: list[np.ndarray]) -> list[np.ndarray]:
    """:func:`interp_rows` of several tables sampled at the same ``xp``, with one bracket
    search: the same values as each on its own (every column is interpolated alone), and no
    stacked copy of the tables."""
    fps = [np.asarray(fp, dtype=float) for fp in fps]
    if len(xp) == 1:
        return [np.repeat(fp, len(x), axis=0) for fp in fps]
    j = np.clip(np.searchsorted(xp, x, side="right") - 1, 0, len(xp) - 2)
    x0 = xp[j]
    w = np.clip((x - x0) / (xp[j + 1] - x0), 0.0, 1.0)[:, None]
    out = []
    for fp in fps:
        f0 = fp[j]
        out.append(f0 + w * (fp[j + 1] - f0))
    return out


def median_spacing(t: np.ndarray) -> float:
    """The median of ``np.diff(t)`` (NaN for fewer than two samples), from a partial sort.

    ``np.median`` (and ``np.quantile``) import ``numpy.ma`` on their first call to check
    for a masked array: 12-15 ms of a ``qsls ingest`` process, whose arrays never are.
    """
    d = np.diff(np.asarray(t))
    n = len(d)
    if n == 0:
        return float("nan")
    k = n // 2
    if n % 2:
        return float(np.partition(d, k)[k])
    part = np.partition(d, [k - 1, k])
    return (float(part[k - 1]) + float(part[k])) / 2
