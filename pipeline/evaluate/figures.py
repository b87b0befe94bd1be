"""Figures of the evaluation (paper, Figures pos_tracking, u_L1_pd and est_err).

Each function takes tables or arrays and returns a matplotlib figure; the stage writes it
through :class:`qsls.pipeline.core.artifacts.StageWriter` (deterministic PNG). Agg backend only.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from qsls.pipeline.core import style

PERCEPTION_ERROR_FIGURE = "perception_error.png"
"""``||e||`` per flight against each controller's bound (paper, Fig. est_err)."""
DISTANCE_FIGURE = "distance_to_training.png"
"""The flown state's distance to the training data, per flight (diagnostic)."""
INPUT_FIGURES = "input_*_vs_pd.png"
"""The robust controller's input against PD's (paper, Fig. u_L1_pd), as a glob."""


def tracking_file(condition: str) -> str:
    """The tracking figure of one perception condition (paper, Fig. pos_tracking)."""
    return f"tracking_{condition}.png"


def input_file(controller: str) -> str:
    """The input figure of one robust controller, one match of :data:`INPUT_FIGURES`."""
    return INPUT_FIGURES.replace("*", controller)


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


def _grid(n: int, width: float = style.WIDTH_IN, height: float = 2.6) -> tuple[Any, list[Any]]:
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
    fig, axes = _grid(len(flights))
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


def tracking_figure(
    traces: Mapping[str, tuple[np.ndarray, np.ndarray]], reference: np.ndarray, title: str
) -> Any:
    """Top view: each controller's true path ``(t, x (n, 6))`` against the reference."""
    fig, axes = style.subplots(width=style.HALF_WIDTH_IN, height=5.9)
    ax = axes[0, 0]
    ax.plot(reference[:, 0], reference[:, 1], color=style.BOUND, ls="--", lw=1.3, label="reference")
    for name, (_, x) in traces.items():
        ax.plot(x[:, 0], x[:, 1], color=style.controller_colour(name), lw=1.2, label=name)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title, loc="left")
    style.legend_below(fig, ncol=2)
    return fig


def input_figure(t: np.ndarray, u: np.ndarray, u_pd: np.ndarray, name: str) -> Any:
    """The robust controller's input against what PD commands from the same estimate."""
    labels = ("pitch (rad)", "roll (rad)", "thrust (N)")
    fig, axes = _grid(3, height=2.0)
    for i, ax in enumerate(axes):
        pd_col = style.controller_colour("pd")
        ax.plot(t, u_pd[:, i], color=pd_col, lw=1.0, label="PD on the same estimate")
        ax.plot(t, u[:, i], color=style.controller_colour(name), lw=1.3, label=name)
        ax.set_ylabel(labels[i])
    axes[0].set_title(f"Input of {name} against PD's on the same estimate", loc="left")
    axes[-1].set_xlabel("t (s)")
    style.legend_below(fig, ncol=2)
    return fig


def error_per_controller_figure(
    traces: Mapping[str, tuple[np.ndarray, np.ndarray]],
    bounds: Mapping[str, float],
    conditions: Sequence[str],
) -> Any:
    """What the verdict compares: per-sample ``||e_k||`` per controller (no averaging), its
    peak ``max_k ||e_k||`` marked and labelled, and the controller's ``gamma_nominal`` on that
    flight (dashed), one panel per condition; the y-axis holds every peak and bound.

    ``traces`` maps ``"condition/controller"`` to ``(t, ||e||)``; ``bounds`` maps the same
    keys to ``gamma_nominal`` (missing or not finite: no bound drawn)."""
    fig, axes = _grid(len(conditions), height=3.0)
    for ax, cond in zip(axes, conditions, strict=False):
        names = [k.split("/", 1)[1] for k in traces if k.split("/", 1)[0] == cond]
        top = 0.0
        for c in names:
            t, e = traces[f"{cond}/{c}"]
            col = style.controller_colour(c)
            ax.plot(t, e, color=col, lw=0.8, label=c)
            if len(e):
                k = int(np.argmax(e))
                ax.plot([t[k]], [e[k]], "v", color=col, ms=7)
                ax.annotate(f"{e[k]:.3g}", (t[k], e[k]), textcoords="offset points",
                            xytext=(4, 4), color=col, fontsize=8.5)  # fmt: skip
                top = max(top, float(e[k]))
            b = bounds.get(f"{cond}/{c}", math.nan)
            if np.isfinite(b):
                ax.axhline(b, color=col, ls="--", lw=1.1)
                top = max(top, float(b))
        ax.set_yscale("log")
        if top > 0:
            ax.set_ylim(top=top * 1.6)
        ax.set_title(
            f"{cond} perception: ||e_k|| per sample, peak marked; dashed: gamma_nominal "
            "(the bound the verdict checks)",
            loc="left",
        )
        ax.set_ylabel("||e||_inf")
    axes[-1].set_xlabel("t (s)")
    style.legend_below(fig, ncol=5)
    return fig


def write_fly_figures(w: Any, outcomes: Any, options: Any, checks: Any = None) -> None:
    """The paper's figures of a fly evaluation: tracking per condition, the robust
    controller's input against PD's on the same estimate, ||e|| against the bound."""

    seed0 = options.seeds[0]
    first = {(o.condition, o.controller): o for o in outcomes if o.seed == seed0}
    for cond in options.conditions:
        traces = {c: (o.t_ctrl, o.x_ctrl) for (k, c), o in first.items() if k == cond}
        if traces:
            ref = next(o.ref_ctrl for (k, _), o in first.items() if k == cond)
            w.write_figure(
                tracking_file(cond),
                tracking_figure(traces, ref, f"{cond} perception, seed {seed0}"),
            )
    # the robust controller's input against PD's from the same estimate
    robust = next(
        (c for c in ("l1_robust_imitation", "l1_robust") if (options.conditions[0], c) in first),
        None,
    )
    if robust is not None:
        o = first[(options.conditions[0], robust)]
        u_pd = o.u_pd
        w.write_figure(input_file(robust), input_figure(o.t_ctrl, o.u_ctrl, u_pd, robust))
    traces_e = {f"{o.condition}/{o.controller}": (o.t_vio, o.e_norm) for o in first.values()}
    w.write_figure(
        PERCEPTION_ERROR_FIGURE,
        error_per_controller_figure(
            traces_e, own_gamma(first.values(), checks), options.conditions
        ),
    )


def own_gamma(outcomes: Any, checks: Any) -> dict[str, float]:
    """``"condition/controller"`` -> ``gamma_nominal`` of the flight the controller flew
    itself (the theorem's bound, as the verdict uses it)."""
    if checks is None or len(checks) == 0 or "gamma_nominal" not in checks:
        return {}
    own = checks[checks["controller"] == checks["flown_by"]]
    by_flight = dict(zip(own["flight"], own["gamma_nominal"], strict=True))
    return {
        f"{o.condition}/{o.controller}": float(by_flight[o.name])
        for o in outcomes
        if o.name in by_flight
    }
