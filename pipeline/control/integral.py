"""Integral action on a constant bias, in the synthesis (docs/guarantee.md#the-bias-term).

A constant acceleration ``beta`` (a heavier vehicle, a steady wind) puts ``D_w beta`` on every
step's disturbance (:attr:`qsls.pipeline.core.plant.LinearModel.bias_dirs`). Acting from the first
tick, it moves the state by the partial sums::

    P_K = sum_{t<=K} Phi_xx(t) H D_w        (K = 0..T; after tap T the response stays P_T)

The problem imposes ``P_T = 0`` on the physical states (integral action: no deviation is left
once ``T`` ticks have passed; the attitude plant's loop states keep the tilt and thrust that
hold the bias off) and bounds ``G_b = max_i w_x,i max_K sum_c |P_K|_ic``, the peak of the
response, which enters the robustness constraint as ``eps_b G_b``. Every ``P_K`` is an affine
map of the free taps, built once per structure with scipy.sparse.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp

from qsls.pipeline.control.achievable import Affine
from qsls.pipeline.core.plant import NX


@dataclass(frozen=True)
class BiasSums:
    """``P_K`` as ``Q z + q``, rows ``(K, i, c)`` row-major over ``taps x nx x nc``."""

    Q: sp.csr_matrix
    q: np.ndarray
    taps: int
    nx: int
    nc: int


def bias_sums(aff: Affine, dirs: np.ndarray) -> BiasSums:
    """The partial sums of ``Phi_xx H`` (the map ``aff``) times the bias directions ``dirs``
    ((nx, nc)): element ``(t, i, j)`` of the taps adds ``dirs[j, c]`` to every row ``(K, i, c)``
    with ``K >= t``."""
    tap, i, j = aff.entry()
    n_t, nx, nc = aff.taps, aff.rows, dirs.shape[1]
    rows, cols, vals = [], [], []
    for c in range(nc):
        d = dirs[j, c]
        nz = np.flatnonzero(d)
        for K in range(n_t):
            sel = nz[tap[nz] <= K]
            rows.append((K * nx + i[sel]) * nc + c)
            cols.append(sel)
            vals.append(d[sel])
    agg = sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
        shape=(n_t * nx * nc, len(i)),
    )
    return BiasSums((agg @ aff.M).tocsr(), agg @ aff.f, n_t, nx, nc)


def integral_action(sums: BiasSums, z: Any, copied: np.ndarray) -> list:
    """``P_T = 0`` on the physical states, as equations in the free taps ``z`` (rows a mirrored
    image copies are its source's, not imposed twice; structurally zero rows are none)."""
    last = np.zeros((sums.taps, sums.nx, sums.nc), dtype=bool)
    last[sums.taps - 1, :NX] = True
    last[:, copied] = False
    keep = last.reshape(-1) & ((np.diff(sums.Q.indptr) > 0) | (sums.q != 0))
    return [sums.Q[keep] @ z + sums.q[keep] == 0] if keep.any() else []


def bias_norm(
    sums: BiasSums, z: Any, wx: np.ndarray, rows: np.ndarray, velocity: np.ndarray,
    copied: np.ndarray,
) -> tuple[Any, dict[int, Any], list]:  # fmt: skip
    """``(G_b, g_b, constraints)``: ``G_b = max_{i in rows} w_x,i g_b,i`` with
    ``g_b,i = max_K sum_c |P_K|_ic`` on an epigraph ``t >= |Q z + q|`` over the rows read
    (``rows``, and the ``velocity`` rows the gate reads; not a mirror's copies)."""
    import cvxpy as cp

    n_t, nx, nc = sums.taps, sums.nx, sums.nc
    mask = np.zeros((n_t, nx, nc), dtype=bool)
    mask[:, rows] = True
    mask[:, velocity] = True
    mask[:, copied] = False
    read = mask.reshape(-1)
    varies = read & (np.diff(sums.Q.indptr) > 0)
    t = cp.Variable(int(varies.sum()), name="abs_bias_sums")
    ex = sums.Q[varies] @ z + sums.q[varies]
    const = np.where(read & ~varies, np.abs(sums.q), 0.0)
    idx = np.arange(n_t * nx * nc)  # (K, i, c) -> (K, i): sum over the directions c
    agg = sp.csr_matrix((np.ones(len(idx)), (idx // nc, idx)), shape=(n_t * nx, len(idx)))
    g = agg[:, varies] @ t + agg @ const
    per_row = {i: cp.max(g[np.arange(n_t) * nx + i]) for i in range(nx) if mask[:, i].any()}
    g_b = cp.max(cp.hstack([wx[i] * per_row[int(i)] for i in rows]))
    return g_b, per_row, [ex <= t, -ex <= t]
