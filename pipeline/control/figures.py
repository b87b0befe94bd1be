"""Figures of ``qsls sweep``: which grid points are feasible, and the largest feasible S.

- ``feasibility.png``: the feasible fraction over two grid axes (S and T when both vary),
  with the largest-feasible-S curve on top when the axes are S and T;
- ``s_max_vs_T.png``: the largest feasible S (bisection) against the horizon T.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from qsls.pipeline.core import style


def _axis_values(table: Any, axis: str) -> tuple[str, list[Any]]:
    col = f"{axis}_value" if f"{axis}_value" in table.columns else axis
    vals = sorted(table[col].unique(), key=lambda v: (str(type(v)), v))
    return col, vals


def _label(v: Any) -> str:
    return f"{v:.3g}" if isinstance(v, float) else str(v)


def _s_max_overlay(ax: Any, xs: list[Any], ys: list[Any], smax: Any) -> None:
    """The largest feasible S per T, placed on the categorical S axis by interpolation."""
    try:
        xv = np.asarray(xs, dtype=float)
    except (TypeError, ValueError):
        return
    curve = smax.groupby("T")["s_max"].min()
    pts = [(np.interp(s, xv, np.arange(len(xv))), ys.index(t)) for t, s in curve.items() if t in ys]
    if pts:
        px, py = zip(*pts, strict=True)
        ax.plot(px, py, color=style.ALERT, ls="--", marker="o", lw=1.8, label="largest feasible S")
        style.legend_below(ax.figure, ncol=1)


def feasibility_figure(table: Any, options: Any, smax: Any) -> Any:
    """Fraction of feasible points over two grid axes (S and T when both vary), with the
    largest-feasible-S curve on top when the axes are S and T."""
    varying = [a for a, v in options.grid.items() if len(v) > 1] or list(options.grid)
    xa = "S" if "S" in varying else varying[0]
    rest = [a for a in varying if a != xa]
    ya = "T" if "T" in rest else (rest[0] if rest else None)
    fig, axes = style.subplots(width=style.WIDTH_IN * 0.75, height=4.4)
    ax = axes[0, 0]
    ax.grid(False)
    xcol, xs = _axis_values(table, xa)
    if ya is None:
        frac = [table.loc[table[xcol] == x, "feasible"].mean() for x in xs]
        ax.bar(range(len(xs)), frac, color=style.OKABE_ITO["bluish_green"])
        ax.set_ylabel("fraction feasible")
        ax.set_ylim(0, 1)
    else:
        ycol, ys = _axis_values(table, ya)
        grid = np.full((len(ys), len(xs)), np.nan)
        for i, y in enumerate(ys):
            for j, x in enumerate(xs):
                sel = table[(table[xcol] == x) & (table[ycol] == y)]
                if len(sel):
                    grid[i, j] = sel["feasible"].mean()
        im = ax.imshow(grid, origin="lower", cmap="cividis", vmin=0, vmax=1, aspect="auto")
        fig.colorbar(im, ax=ax, label="fraction feasible", shrink=0.9, pad=0.02)
        for i in range(len(ys)):
            for j in range(len(xs)):
                if np.isfinite(grid[i, j]):
                    ink = "black" if grid[i, j] > 0.5 else "white"
                    ax.text(j, i, f"{grid[i, j]:.2g}", ha="center", va="center", color=ink)
        ax.set_yticks(range(len(ys)), [_label(y) for y in ys])
        ax.set_ylabel(ya)
        if xa == "S" and ya == "T" and smax is not None and len(smax):
            _s_max_overlay(ax, xs, ys, smax)
    ax.set_xticks(range(len(xs)), [_label(x) for x in xs], rotation=30)
    ax.set_xlabel(xa)
    ax.set_title("Feasible fraction of the sweep", loc="left")
    return fig


def s_max_figure(smax: Any) -> Any:
    """The largest feasible S against T, one line per setting of the other axes."""
    fig, axes = style.subplots(width=style.WIDTH_IN * 0.75, height=4.2)
    ax = axes[0, 0]
    keys = [
        k for k in ("eps_e", "radius", "eps_w", "delta", "strictly_proper") if smax[k].nunique() > 1
    ]
    groups = smax.groupby(keys) if keys else [((), smax)]
    for n, (name, g) in enumerate(groups):
        if n >= 8:
            break
        g = g.sort_values("T")
        label = ", ".join(
            f"{k}={_label(v)}"
            for k, v in zip(keys, name if isinstance(name, tuple) else (name,), strict=True)
        )
        ax.plot(
            g["T"],
            g["s_max"],
            marker="o",
            color=style.CYCLE[n % len(style.CYCLE)],
            label=label or "largest feasible S",
        )
    ax.set_xlabel("horizon T (steps)")
    ax.set_ylabel("largest feasible S")
    ax.set_ylim(bottom=0)
    style.legend_right(ax)
    ax.set_title("Largest feasible S against T", loc="left")
    return fig
