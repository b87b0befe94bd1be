"""Estimate the constant clock offset between the VIO and the truth streams.

Convention (DESIGN.md): ``tau = time_offset_s`` is added to truth stamps to put them on
the VIO clock; the truth position at VIO time ``t`` is ``p_truth(t - tau)``.

Method: position mismatch after alignment, minimized over the 1-D offset.
For a candidate ``tau`` the truth positions are interpolated at ``t_i - tau`` for the VIO
stamps ``t_i``, the VIO positions are aligned to them with the requested alignment
(:func:`qsls.pipeline.align.fit_alignment`: ``4dof``, ``se3``, or ``none``), and the cost is
the RMS of the residual ``||R p_vio_i + t - p_truth(t_i - tau)||``. The search is
coarse-to-fine: the cost on a grid of ``step_s`` (20 ms) over ``[-max_offset_s, max_offset_s]``
using at most 1000 evenly spaced samples, then Brent's bounded minimization (to 1 us) on
all samples within one grid step either side of the best grid point. The cost is smooth
and single-minimum over far more than one grid step (position changes slowly compared
with 20 ms), so the grid only has to land in the right basin.

Why this and not velocity-magnitude cross-correlation (which is also frame-invariant): the
position residual uses the whole signal (low frequencies included), needs no
differentiation of noisy positions, is what the alignment afterwards minimizes anyway
(so offset and alignment are consistent), and its minimum is sharp whenever the vehicle
moves; speed correlation is weak in hover and biased by velocity noise. Alignment inside
the cost makes it frame-invariant too.

The same VIO samples enter every candidate: those whose stamps stay inside the truth's
time range for every offset searched (otherwise the cost would change with the sample set,
favouring offsets with less overlap). At most ``max_samples`` evenly spaced VIO samples
are used.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qsls.pipeline.align import fit_alignment
from qsls.pipeline.errors import InputError


@dataclass(frozen=True)
class OffsetEstimate:
    offset_s: float
    rms_m: float  # position RMS after alignment at the offset
    samples: int  # VIO samples used
    search_s: float  # half-width of the search range actually used
    at_edge: bool  # best grid point on the edge of the search range


def _cost(
    tau_s: float,
    tv: np.ndarray,
    pv: np.ndarray,
    tt: np.ndarray,
    pt: np.ndarray,
    method: str,
) -> float:
    q = tv - tau_s
    truth = np.column_stack([np.interp(q, tt, pt[:, k]) for k in range(3)])
    al = fit_alignment(pv, truth, method)
    r = al.apply(pv) - truth
    return float(np.sqrt(np.mean(np.sum(r * r, axis=1))))


def estimate_offset(
    vio_ns: np.ndarray,
    vio_p: np.ndarray,
    truth_ns: np.ndarray,
    truth_p: np.ndarray,
    *,
    method: str = "4dof",
    max_offset_s: float = 2.0,
    step_s: float = 0.02,
    min_overlap_s: float = 3.0,
    max_samples: int = 4000,
    coarse_samples: int = 1000,
) -> OffsetEstimate:
    """The offset ``tau`` (s) minimizing the aligned position RMS (module docstring)."""
    # work in seconds relative to a common origin (float64 keeps sub-microsecond precision)
    t0 = int(min(vio_ns[0], truth_ns[0]))
    tv_all = (np.asarray(vio_ns, np.int64) - t0) * 1e-9
    tt = (np.asarray(truth_ns, np.int64) - t0) * 1e-9
    pt = np.asarray(truth_p, float)
    overlap = min(tv_all[-1], tt[-1]) - max(tv_all[0], tt[0])
    search = float(max_offset_s)
    # keep at least half the overlap (and min_overlap) usable for every offset searched
    if overlap > 0:
        search = min(search, max((overlap - min_overlap_s) / 2, overlap / 4))
    keep = (tv_all >= tt[0] + search) & (tv_all <= tt[-1] - search)
    if overlap <= 0 or keep.sum() < 10:
        raise InputError(
            "the VIO and truth streams overlap too little in time to estimate the clock "
            f"offset ({max(overlap, 0):.2f} s); give --time-offset SECONDS"
        )
    idx = np.flatnonzero(keep)
    if len(idx) > max_samples:
        idx = idx[np.linspace(0, len(idx) - 1, max_samples).round().astype(int)]
    tv = tv_all[idx]
    pv = np.asarray(vio_p, float)[idx]
    # coarse: a grid of step_s on at most coarse_samples of the samples
    sub = np.linspace(0, len(tv) - 1, min(len(tv), coarse_samples)).round().astype(int)
    n_grid = max(1, int(np.floor(search / step_s)))
    grid = np.arange(-n_grid, n_grid + 1) * step_s
    costs = np.array([_cost(g, tv[sub], pv[sub], tt, pt, method) for g in grid])
    k = int(np.argmin(costs))
    at_edge = k in (0, len(grid) - 1) and len(grid) > 1
    # fine: Brent's method on all samples within one grid step either side
    from scipy.optimize import minimize_scalar

    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    best = float(grid[k])
    rms = _cost(best, tv, pv, tt, pt, method)
    if hi > lo:
        res = minimize_scalar(
            _cost, bounds=(lo, hi), args=(tv, pv, tt, pt, method), method="bounded",
            options={"xatol": 1e-6},
        )  # fmt: skip
        if float(res.fun) <= rms:
            best, rms = float(res.x), float(res.fun)
    return OffsetEstimate(best, rms, len(tv), search, at_edge)
