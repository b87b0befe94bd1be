"""Figures of the bound check (paper, Figure est_err); the fly stage's own (Figures
pos_tracking and u_L1_pd) are in :mod:`qsls.pipeline.fly.figures`.

Each function takes tables or arrays and returns a matplotlib figure; the stage writes it
through :class:`qsls.pipeline.core.artifacts.StageWriter` (deterministic PNG). Agg backend only.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from qsls.pipeline.core import style

PERCEPTION_ERROR_FIGURE = "perception_error.png"
"""``||e||`` per flight against each controller's bound (paper, Fig. est_err)."""
DISTANCE_FIGURE = "distance_to_training.png"
"""The flown state's distance to the training data, per flight (diagnostic)."""


def smooth(signal: np.ndarray, dt: float, tau: float) -> np.ndarray:
    """First-order average with time constant ``tau`` (the paper's figure): ``s_k = s_{k-1} +
    alpha (x_k - s_{k-1})``, ``alpha = 1 - exp(-dt / tau)``, started at ``x_0``."""
    from scipy.signal import lfilter

    x = np.asarray(signal, dtype=float)
    if tau <= 0 or len(x) == 0:
        return x.copy()
    alpha = 1.0 - math.exp(-dt / tau)
    out, _ = lfilter([alpha], [1.0, alpha - 1.0], x, zi=[(1.0 - alpha) * x[0]])
    return out


def panel_grid(n: int, width: float = style.WIDTH_IN, height: float = 2.6) -> tuple[Any, list[Any]]:
    fig, axes = style.subplots(max(n, 1), 1, width=width, height=0.6 + height * max(n, 1))
    return fig, [a for a in axes[:, 0]]


def _dt(t: np.ndarray) -> float:
    return float(np.median(np.diff(t))) if len(t) > 1 else 0.1


def perception_error_figure(samples: pd.DataFrame, smooth_s: float = 1.0) -> Any:
    """``||e_k||`` over time per flight, smoothed with a ``smooth_s`` time constant, with each
    controller's ``gamma_nominal`` (solid: the theorem's bound, on flights it flew itself),
    ``gamma_strict`` (dashed) and the per-sample premise curve ``gamma(d_k)`` (dotted: it
    tests the error model, not the controller)."""
    flights = list(dict.fromkeys(samples["flight"]))
    fig, axes = panel_grid(len(flights))
    for ax, name in zip(axes, flights, strict=False):
        s = samples[samples["flight"] == name]
        first = s[s["controller"] == s["controller"].iloc[0]]
        t = first["t"].to_numpy()
        e = first["error_norm"].to_numpy()
        ax.plot(t, e, color=style.LIGHT, lw=0.7, label="||e||")
        if smooth_s > 0:
            ax.plot(
                t,
                smooth(e, _dt(t), smooth_s),
                color=style.NEUTRAL,
                lw=1.3,
                label=f"||e|| ({smooth_s:g} s avg)",
            )
        for c, g in s.groupby("controller", sort=False):
            col = style.controller_colour(str(c))
            gn = g["gamma_nominal"].iloc[0] if "gamma_nominal" in g else np.nan
            if np.isfinite(gn):
                ax.axhline(gn, color=col, ls="-", lw=1.2, label=f"{c} gamma_nominal")
            gs = g["gamma_strict"].iloc[0]
            if np.isfinite(gs):
                ax.axhline(gs, color=col, ls="--", lw=1, label=f"{c} gamma_strict")
            gk = g["gamma"].to_numpy()
            if np.all(np.isfinite(gk)):
                ax.plot(g["t"], gk, color=col, ls=":", lw=1, label=f"{c} gamma(d), premise curve")
            over = g["error_norm"].to_numpy() > gk
            if np.any(over):
                ax.plot(
                    g["t"].to_numpy()[over], g["error_norm"].to_numpy()[over], "x", color=col, ms=5
                )
        ax.set_yscale("log")
        ax.set_title(f"{name} (x: above gamma(d))", loc="left")
        ax.set_ylabel("||e||_inf")
        style.legend_right(ax)
    axes[-1].set_xlabel("t (s)")
    return fig


def distance_figure(samples: pd.DataFrame, radius: float) -> Any:
    """Each flight's distance to the nearest training state over time, and the radius."""
    fig, axes = style.subplots(width=style.WIDTH_IN, height=3.6)
    ax = axes[0, 0]
    dashes = ("-", "--", ":", "-.")
    for i, (name, g) in enumerate(samples.groupby("flight", sort=False)):
        g = g[g["controller"] == g["controller"].iloc[0]]
        by = g["flown_by"].iloc[0] if "flown_by" in g else None
        col = style.controller_colour(str(by)) if by else style.CYCLE[i % len(style.CYCLE)]
        ax.plot(g["t"], g["distance"], color=col, ls=dashes[(i // 8) % 4], lw=1.1, label=str(name))
    if np.isfinite(radius):
        ax.axhline(radius, color=style.BOUND, ls="--", lw=1, label=f"radius r = {radius:g}")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("distance to training (inf norm)")
    ax.set_title("Distance of the flown state to the nearest training state", loc="left")
    style.legend_right(ax)
    return fig
