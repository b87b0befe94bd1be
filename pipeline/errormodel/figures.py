"""Figures of ``qsls fit``: where the S-slope and ``eps_e`` come from.

- ``slope_distribution.png``: the pair slopes (and each sample's largest slope) on a log
  scale, with the percentiles and the max marked;
- ``error_norm.png``: ``||e||`` over time per flight, with ``eps_e``, its percentiles, the
  excluded samples and the samples of the worst pairs;
- ``worst_pairs.png``: the worst pairs drawn on the trajectory, in position and velocity.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from qsls.pipeline.core import style
from qsls.pipeline.errormodel.model import ErrorModel
from qsls.pipeline.errormodel.slopes import PairSlopes

SLOPE_DISTRIBUTION_FIGURE = "slope_distribution.png"
ERROR_NORM_FIGURE = "error_norm.png"
WORST_PAIRS_FIGURE = "worst_pairs.png"
FIGURES = (SLOPE_DISTRIBUTION_FIGURE, ERROR_NORM_FIGURE, WORST_PAIRS_FIGURE)
"""The fit's figures, in the order the report shows them."""

_MAX_PANELS = 6


def make_figures(model: ErrorModel, ps: PairSlopes, tr: Any, idx: np.ndarray, qs) -> dict:
    """All figures by file name (``tr``: the fit's training data, ``idx``: kept samples)."""
    return {
        SLOPE_DISTRIBUTION_FIGURE: slope_distribution(model, ps),
        ERROR_NORM_FIGURE: error_norm(model, tr),
        WORST_PAIRS_FIGURE: worst_pairs(model, tr, idx),
    }


def slope_distribution(model: ErrorModel, ps: PairSlopes):
    """Histogram of pair slopes (log x) with percentiles and the max marked."""
    fig, axes = style.subplots(width=style.WIDTH_IN, height=4.6)
    ax = axes[0, 0]
    h = ps.histogram
    lo, hi = h.edges()
    counts = h.counts
    pos = (counts > 0) & (lo > 0)
    n_zero = float(counts[(counts > 0) & (lo <= 0)].sum())
    if pos.any():
        mids = np.sqrt(lo[pos] * hi[pos])
        a, b = np.log10(mids.min()), np.log10(max(mids.max(), model.s_slope.max))
        if b - a < 1e-6:
            a, b = a - 0.5, b + 0.5
        edges = np.logspace(a - 0.02, b + 0.02, 81)
        hc, _ = np.histogram(mids, bins=edges, weights=counts[pos])
        ax.stairs(
            hc / max(h.total, 1), edges, fill=True, alpha=0.5, color=style.CYCLE[0], label="pairs"
        )
        loc = ps.local_max[np.isfinite(ps.local_max) & (ps.local_max > 0)]
        if len(loc):
            lc, _ = np.histogram(np.clip(loc, edges[0], edges[-1]), bins=edges)
            ax.stairs(
                lc / len(loc),
                edges,
                color=style.OKABE_ITO["bluish_green"],
                lw=1.4,
                label="largest slope per sample",
            )
        ax.set_xscale("log")
    dashes = ("--", "-.", ":", (0, (5, 1, 1, 1, 1, 1)))
    for i, (k, v) in enumerate(model.s_slope.percentiles.items()):
        if np.isfinite(v) and v > 0:
            ax.axvline(
                v, color=style.NEUTRAL, ls=dashes[i % len(dashes)], lw=1.3, label=f"{k} = {v:.3g}"
            )
    ax.axvline(model.s_slope.max, color=style.ALERT, lw=2.0, label=f"max = {model.s_slope.max:.3g}")
    ax.set_xlabel("slope ||e_i - e_j|| / ||x_i - x_j||  (infinity norms)")
    ax.set_ylabel("fraction")
    extra = f", {int(n_zero)} zero slopes" if n_zero else ""
    ax.set_title(
        f"S-slope: {model.n_pairs:,} pairs, radius {model.radius:g}, "
        f"min separation {model.min_separation:.3g}{extra}",
        loc="left",
    )
    style.legend_right(ax)
    ax.grid(True, which="both", alpha=0.25)
    return fig


def error_norm(model: ErrorModel, tr: Any):
    """``||e||_inf`` over time per flight."""
    names = tr.names
    panels = len(names) if len(names) <= _MAX_PANELS else 1
    fig, axes = style.subplots(panels, 1, width=style.WIDTH_IN, height=1.0 + 2.0 * panels)
    enorm = np.abs(tr.e).max(axis=1)
    worst_t: dict[str, list[float]] = {}
    for w in model.worst_pairs:
        worst_t.setdefault(w.flight, []).append(w.t_i)
        worst_t.setdefault(w.flight_j or w.flight, []).append(w.t_j)
    for k, name in enumerate(names):
        ax = axes[k if panels > 1 else 0, 0]
        sel = tr.flight_idx == k
        t, en, keep = tr.t[sel], enorm[sel], tr.keep[sel]
        col = style.CYCLE[k % len(style.CYCLE)] if panels == 1 else style.NEUTRAL
        ax.plot(
            t, np.where(keep, en, np.nan), color=col, lw=0.9, label=name if panels == 1 else None
        )
        if (~keep).any():
            ax.plot(
                t[~keep],
                en[~keep],
                "x",
                color=style.LIGHT,
                ms=4,
                label="excluded" if k == 0 else None,
            )
        if name in worst_t:
            tw = np.asarray(worst_t[name])
            yw = np.interp(tw, t, en)
            ax.plot(
                tw,
                yw,
                "o",
                mfc="none",
                color=style.ALERT,
                ms=6,
                label="worst-pair samples" if k == 0 or panels > 1 else None,
            )
        if panels > 1 or k == 0:
            ax.axhline(
                model.eps_e, color=style.BOUND, lw=1.3, label=f"eps_e (max) = {model.eps_e:.3g}"
            )
            for q, v in model.eps_e_percentiles.items():
                ax.axhline(v, color=style.NEUTRAL, ls=":", lw=0.9)
                ax.annotate(
                    q,
                    (1.005, v),
                    xycoords=("axes fraction", "data"),
                    fontsize=8.5,
                    va="center",
                    ha="left",
                )
        if panels > 1:
            ax.set_title(name, loc="left")
        ax.set_ylabel("||e||_inf")
    axes[-1, 0].set_xlabel("t (s)")
    style.legend_below(fig, ncol=4)
    return fig


def worst_pairs(model: ErrorModel, tr: Any, idx: np.ndarray):
    """The worst pairs on the trajectory: position (px, py) and velocity (vx, vy)."""
    fig, grid = style.subplots(1, 2, width=style.WIDTH_IN, height=5.0)
    axes = grid[0]
    x = tr.x[idx]
    n = len(x)
    step = max(1, n // 50000)
    pairs = model.worst_pairs
    import matplotlib

    cmap = matplotlib.colormaps["cividis"]
    for ax, (a, b), lab in zip(axes, [(0, 1), (3, 4)], ["p", "v"], strict=True):
        ax.plot(x[::step, a], x[::step, b], ".", color=style.LIGHT, ms=1.5, label="training states")
        for r, w in reversed(list(enumerate(pairs))):
            c = cmap(0.85 * r / max(1, len(pairs) - 1))
            ax.plot([w.x_i[a], w.x_j[a]], [w.x_i[b], w.x_j[b]], "-o", color=c, ms=3.5, lw=1.5)
            if r < 5:
                ax.annotate(
                    str(r + 1),
                    (w.x_i[a], w.x_i[b]),
                    fontsize=9,
                    xytext=(3, 3),
                    textcoords="offset points",
                )
        unit = "m" if lab == "p" else "m/s"
        ax.set_xlabel(f"{lab}x ({unit})")
        ax.set_ylabel(f"{lab}y ({unit})")
        ax.set_aspect("equal", adjustable="datalim")
    if pairs:
        axes[0].set_title(
            f"position: {len(pairs)} worst pairs (1 = largest slope {pairs[0].slope:.3g})",
            loc="left",
        )
    axes[1].set_title("velocity", loc="left")
    style.legend_below(fig, ncol=2)
    return fig
