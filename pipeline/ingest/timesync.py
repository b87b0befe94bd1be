"""Estimate the constant clock offset between the VIO and the truth streams.

Convention (docs/conventions.md#clocks): ``tau = time_offset_s`` is added to truth stamps to put them on
the VIO clock; the truth position at VIO time ``t`` is ``p_truth(t - tau)``.

Position term. For a candidate ``tau`` the truth positions are interpolated at
``t_i - tau`` for the VIO stamps ``t_i``, the VIO positions are aligned to them with the
requested alignment (:func:`qsls.pipeline.ingest.align.fit_alignment`: ``4dof``, ``se3``, or
``none``), and ``P(tau)`` is the mean square of the residual
``||R p_vio_i + t - p_truth(t_i - tau)||``.

Attitude (gravity) term. On a circle flown at constant yaw a clock shift moves every truth
point along the circle by the same angle, i.e. it is a rotation about the circle's centre,
which the ``4dof`` alignment (yaw + translation) absorbs: ``P`` is nearly flat in ``tau``
and slowly varying VIO errors decide where its minimum lands (2.5-13 ms off on the
default ``qsls simulate`` circle). The attitude breaks the symmetry. Under a 4-DOF gauge
(the two world frames differ by a yaw and a translation, z gravity-aligned in both) the
gravity direction in the body frame ``g_b(t) = R_wb(t)^T e_z`` (the third row of
``R_wb``) is the same in both streams; on a circle it turns in the body x-y plane with the
circle's period, so it pins the time. ``G(tau)`` is the mean square of
``d_i - mean(d)`` with ``d_i = g_b,vio(t_i) - g_b,truth(t_i - tau)``: removing the mean
difference absorbs a constant small tilt between the two body frames (a motion-capture
rigid body is rarely aligned with the IMU): a tilt ``theta`` about a body x/y axis shifts
``g_b`` by a nearly constant ``theta`` (the rest, ``theta`` times the tilt amplitude, is
in z and second order in the time shift).

Combined cost. With both terms the estimate minimizes ``log P(tau) + log G(tau)``: the
profile likelihood of Gaussian residuals with an unknown variance per term (the variances
estimated at each ``tau``). Near the minimum this is ``P/P_min + G/G_min``, each term
normalized by its own scale, so the result is the two terms' minima weighted by their
relative sharpness: on the circle the sharp ``G`` dominates the flat ``P``; in hover,
where ``g_b`` is constant and ``G`` flat, ``P`` decides; on a figure-eight both agree.
Neither term needs a weight or a unit conversion. Why not ``G`` alone: it carries no
information when the vehicle barely tilts, and the position term keeps the estimate
consistent with the alignment fitted afterwards. The attitude term is used when both
streams carry orientations that move (``g_b`` varies by more than ``min_tilt_rad`` RMS
in each) and the alignment is ``4dof`` or ``none``; with ``se3`` the VIO world z need
not be vertical, ``g_b`` is not comparable, and the estimate is position only (``P``),
unchanged.

Limitation: a constant misalignment of the two body frames about the body z axis turns
``g_b``'s horizontal part like a time shift does on a constant-yaw circle (both are a
rotation about body z), so it biases the estimate by ``psi / omega`` (``omega`` the
circle's angular rate); nothing in positions and attitudes separates the two there (the
position term damps it: 2 degrees about body z moved the estimate 6-7.6 ms on the default
``qsls simulate`` circle, seeds 0-7, against 22 ms from ``psi / omega``). Tilts about body
x/y (tested at 2 degrees) move it less than 0.1 ms.

Search: coarse-to-fine: the cost on a grid of ``step_s`` (20 ms) over
``[-max_offset_s, max_offset_s]`` using at most 1000 evenly spaced samples, then a
golden-section search (:func:`golden_section`, to 1 us) on all samples within one grid step
either side of the best grid point. Both terms are smooth and single-minimum over far more
than one grid step (position and attitude change slowly compared with 20 ms), so the grid
only has to land in the right basin, and inside it the bracket holds one minimum, which is
all golden-section search needs. scipy's bounded Brent was used before; importing
``scipy.optimize`` cost 0.19 s, half a 200k-message ingest. A test checks the two on a
simulated circle: the same minimum to 2 us with the attitude term; on the nearly flat
position-only cost they stop 0.9 ms apart, golden-section at the lower cost.

Why this and not velocity-magnitude cross-correlation (which is also frame-invariant): the
position residual uses the whole signal (low frequencies included), needs no
differentiation of noisy positions, is what the alignment afterwards minimizes anyway
(so offset and alignment are consistent), and its minimum is sharp whenever the vehicle
moves (other than along a circle, see above); speed correlation is weak in hover and
biased by velocity noise. Alignment inside the cost makes it frame-invariant too.

The same VIO samples enter every candidate: those whose stamps stay inside the truth's
time range for every offset searched (otherwise the cost would change with the sample set,
favouring offsets with less overlap). At most ``max_samples`` evenly spaced VIO samples
are used.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.rotations import gravity_in_body
from qsls.pipeline.ingest.align import best_rotation
from qsls.pipeline.ingest.resample import interp_rows_many


@dataclass(frozen=True)
class OffsetEstimate:
    offset_s: float
    rms_m: float  # position RMS after alignment at the offset
    samples: int  # VIO samples used
    search_s: float  # half-width of the search range actually used
    at_edge: bool  # best grid point on the edge of the search range
    tilt_rms: float | None = None  # RMS of the g_b mismatch (mean removed) at the offset
    uses_attitude: bool = False  # the cost includes the gravity-direction term


def _terms(
    tau_s: float,
    tv: np.ndarray,
    pv: np.ndarray,
    gv: np.ndarray | None,
    tt: np.ndarray,
    truth: np.ndarray | tuple[np.ndarray, ...],
    method: str,
) -> tuple[float, float | None]:
    """``P(tau)`` (m^2) and ``G(tau)`` (None without attitudes), module docstring; ``truth``
    holds the truth's positions, then its ``g_b`` when ``gv`` is given: as the columns of
    one array, or as the tuple ``(positions, g_b)`` (one interpolation for both, the same
    values)."""
    tables = list(truth) if isinstance(truth, tuple) else [truth]
    at = np.hstack(interp_rows_many(tv - tau_s, tt, tables))
    pt = at[:, :3]
    if method == "none":
        r = pv - pt
    else:  # R (pv - mean) + mean(pt) - pt: fit_alignment's transform, its residual
        a, b = pv - pv.mean(axis=0), pt - pt.mean(axis=0)
        r = a @ best_rotation(a, b, method).T - b
    n = len(r)
    pos = float(np.einsum("ij,ij->", r, r)) / n
    if gv is None:
        return pos, None
    d = gv - at[:, 3:]
    d -= d.mean(axis=0)
    return pos, float(np.einsum("ij,ij->", d, d)) / n


def _cost(tau_s: float, *data: Any) -> float:
    """RMS position residual, or ``log P + log G`` with attitudes (module docstring);
    ``data`` as :func:`_terms` takes it."""
    pos, tilt = _terms(tau_s, *data)
    if tilt is None:
        return float(np.sqrt(pos))
    return float(np.log(pos + 1e-18) + np.log(tilt + 1e-18))


_INV_PHI = (5**0.5 - 1) / 2  # 1 / golden ratio


def golden_section(
    f: Callable[[float], float], lo: float, hi: float, xatol: float
) -> tuple[float, float]:
    """``(x, f(x))`` minimizing ``f`` on ``[lo, hi]`` to ``xatol``, for ``f`` with one
    minimum there: golden-section search.

    Of the bracket ``[a, b]`` and its inner points ``c = b - (b - a) / phi``,
    ``d = a + (b - a) / phi`` (``phi`` the golden ratio), the part ``[a, d]`` is kept when
    ``f(c) <= f(d)``, else ``[c, b]``; the kept inner point is an inner point of the new
    bracket, so each step costs one evaluation and shrinks the bracket by ``1 / phi``. The
    steps are counted in advance, ``ceil(log((hi - lo) / xatol) / log(phi))``, so the search
    ends even where floating point cannot resolve ``xatol``: 2 + 23 evaluations for 40 ms to
    1 us (scipy's bounded Brent needs fewer on a smooth cost, 6 on a parabola, but costs its
    import). The result is the better of the last two inner points.
    """
    if not xatol > 0:
        raise ValueError("xatol must be positive")
    a, b = lo, hi
    steps = math.ceil(math.log((b - a) / xatol) / -math.log(_INV_PHI)) if b - a > xatol else 0
    c, d = b - _INV_PHI * (b - a), a + _INV_PHI * (b - a)
    fc, fd = f(c), f(d)
    for _ in range(steps):
        if fc <= fd:
            b, d, fd = d, c, fc
            c = b - _INV_PHI * (b - a)
            fc = f(c)
        else:
            a, c, fc = c, d, fd
            d = a + _INV_PHI * (b - a)
            fd = f(d)
    return (c, fc) if fc <= fd else (d, fd)


_ROWS = 1 << 16  # rows computed at once (bounded temporaries on long flights)


def gravity_rows(q: np.ndarray) -> np.ndarray:
    """:func:`gravity_in_body` ``(n, 3)``, computed block by block into one array."""
    out = np.empty((len(q), 3))
    for a in range(0, len(q), _ROWS):
        out[a : a + _ROWS] = gravity_in_body(q[a : a + _ROWS])
    return out


def _tilt_rms(g: np.ndarray) -> float:
    """RMS of ``g - mean(g)`` over the rows (how much the attitude moves), summed in blocks."""
    mu = g.mean(axis=0)
    total = sum(float(np.sum((g[a : a + _ROWS] - mu) ** 2)) for a in range(0, len(g), _ROWS))
    return float(np.sqrt(total / len(g)))


_COARSE = 5
"""Grid steps between the points of the first, coarser pass of the offset search."""


def _attitude_terms(
    vio_q: np.ndarray | None,
    truth_q: np.ndarray | None,
    idx: np.ndarray,
    pt: np.ndarray,
    method: str,
    min_tilt_rad: float,
) -> tuple[np.ndarray | None, np.ndarray | tuple[np.ndarray, ...]]:
    """The VIO's gravity directions in its body frame at samples ``idx`` and the truth's
    table to compare with (positions, and its gravity directions), when both orientations
    are given, ``method`` is ``4dof`` or ``none`` and the attitudes move; else ``(None,
    positions)``: level (or identity) attitudes have nothing to compare."""
    if vio_q is None or truth_q is None or method not in ("4dof", "none"):
        return None, pt
    gv = gravity_in_body(np.asarray(vio_q)[idx])
    truth_q = np.asarray(truth_q)
    gt = truth_q if truth_q.shape[1] == 3 else gravity_rows(truth_q)
    if min(_tilt_rms(gv), _tilt_rms(gt)) > min_tilt_rad:
        return gv, (pt, gt)
    return None, pt


def estimate_offset(
    vio_ns: np.ndarray,
    vio_p: np.ndarray,
    truth_ns: np.ndarray,
    truth_p: np.ndarray,
    *,
    vio_q: np.ndarray | None = None,
    truth_q: np.ndarray | None = None,
    method: str = "4dof",
    max_offset_s: float = 2.0,
    step_s: float = 0.02,
    min_overlap_s: float = 3.0,
    max_samples: int = 4000,
    coarse_samples: int = 1000,
    min_tilt_rad: float = 0.005,
) -> OffsetEstimate:
    """The offset ``tau`` (s) minimizing the aligned position RMS, with the gravity
    direction in the body frame when both orientations ``vio_q``, ``truth_q`` (``x y z w``)
    are given, move, and ``method`` is ``4dof`` or ``none`` (module docstring). ``truth_q``
    may also be the truth's gravity directions ``(n, 3)`` (:func:`gravity_rows`), the same
    values."""
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
    gv, table = _attitude_terms(vio_q, truth_q, idx, pt, method, min_tilt_rad)
    args = (gv, tt, table, method)
    # coarse: a grid of step_s on at most coarse_samples of the samples
    sub = np.linspace(0, len(tv) - 1, min(len(tv), coarse_samples)).round().astype(int)
    coarse_args = (tv[sub], pv[sub], None if gv is None else gv[sub], *args[1:])
    n_grid = max(1, int(np.floor(search / step_s)))
    grid = np.arange(-n_grid, n_grid + 1) * step_s

    def cost_at(j: np.ndarray) -> np.ndarray:
        return np.array([_cost(grid[i], *coarse_args) for i in j])

    # every COARSE-th grid point first, then the grid around the best of those: the cost
    # varies on the time scale of the motion (seconds), far wider than COARSE * step_s
    coarse = np.arange(0, len(grid), _COARSE)
    if coarse[-1] != len(grid) - 1:
        coarse = np.append(coarse, len(grid) - 1)
    kc = int(coarse[np.argmin(cost_at(coarse))])
    near = np.arange(max(kc - _COARSE, 0), min(kc + _COARSE + 1, len(grid)))
    k = int(near[np.argmin(cost_at(near))])
    at_edge = k in (0, len(grid) - 1) and len(grid) > 1
    # fine: golden-section search on all samples within one grid step either side
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    best = float(grid[k])
    cost = _cost(best, tv, pv, *args)
    if hi > lo:
        x, fx = golden_section(lambda tau: _cost(tau, tv, pv, *args), float(lo), float(hi), 1e-6)
        if fx <= cost:
            best = x
    pos, tilt = _terms(best, tv, pv, *args)
    return OffsetEstimate(
        best,
        float(np.sqrt(pos)),
        len(tv),
        search,
        at_edge,
        tilt_rms=None if tilt is None else float(np.sqrt(tilt)),
        uses_attitude=tilt is not None,
    )
