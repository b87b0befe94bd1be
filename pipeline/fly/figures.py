"""Figures of the fly stage (paper, Figures pos_tracking, u_L1_pd and est_err): each
controller's path per perception condition, the robust controller's input against PD's on the
same estimate, and ``||e||`` per controller against the bound the verdict checks
(docs/evaluation.md, Flying the controllers).

Each function takes tables or arrays and returns a matplotlib figure; the stage writes it
through :class:`qsls.pipeline.core.artifacts.StageWriter` (deterministic PNG). Agg backend only.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from qsls.pipeline.core import style
from qsls.pipeline.evaluate.figures import PERCEPTION_ERROR_FIGURE, panel_grid

INPUT_FIGURES = "input_*_vs_pd.png"
"""The robust controller's input against PD's (paper, Fig. u_L1_pd), as a glob."""


def tracking_file(condition: str) -> str:
    """The tracking figure of one perception condition (paper, Fig. pos_tracking)."""
    return f"tracking_{condition}.png"


def input_file(controller: str) -> str:
    """The input figure of one robust controller, one match of :data:`INPUT_FIGURES`."""
    return INPUT_FIGURES.replace("*", controller)


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
    fig, axes = panel_grid(3, height=2.0)
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
    fig, axes = panel_grid(len(conditions), height=3.0)
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
