"""One look for every figure qsls draws: colour-blind-safe colours, one per controller, and
sizes that read at the size the report shows them.

Colours are the Okabe-Ito palette (Okabe & Ito 2008, distinguishable under the common
colour-vision deficiencies). A controller keeps its colour in every figure of every stage:
the paper's four controllers and the SE3 controller that records the training flights have
fixed colours; any other name gets a spare colour chosen by a stable hash of the name (the
same name gives the same colour in every run).

Figures are drawn at the pixel width the report shows them (``WIDTH_IN`` inches at the
stages' 110 dpi is about the report's column), with fonts of 10-11 pt (14-17 px there).
"""

from __future__ import annotations

import zlib
from typing import Any

OKABE_ITO = {
    "black": "#000000",
    "orange": "#E69F00",
    "sky_blue": "#56B4E9",
    "bluish_green": "#009E73",
    "yellow": "#F0E442",
    "blue": "#0072B2",
    "vermillion": "#D55E00",
    "reddish_purple": "#CC79A7",
}

# the three l1_* controllers in three hue families (purple, blue, green; sky blue beside
# blue read as one), every pair at least 15 CIELAB units apart also under simulated
# protanopia, deuteranopia and tritanopia (tests/test_new_user.py)
CONTROLLER_COLOURS = {
    "pd": OKABE_ITO["vermillion"],
    "l1_nominal": OKABE_ITO["reddish_purple"],
    "l1_robust": OKABE_ITO["blue"],
    "l1_robust_imitation": OKABE_ITO["bluish_green"],
    "se3": OKABE_ITO["orange"],
}
_SPARE = (OKABE_ITO["sky_blue"], "#8C6D1F", "#555555", "#9A9AE6")
# series that are not controllers (flights, percentiles): the palette in a fixed order
CYCLE = (
    OKABE_ITO["blue"],
    OKABE_ITO["orange"],
    OKABE_ITO["bluish_green"],
    OKABE_ITO["vermillion"],
    OKABE_ITO["reddish_purple"],
    OKABE_ITO["sky_blue"],
    OKABE_ITO["yellow"],
    OKABE_ITO["black"],
)
NEUTRAL = "#4D4D4D"  # data that is not a controller's (||e|| itself, training states)
LIGHT = "#BFBFBF"
BOUND = OKABE_ITO["black"]
ALERT = OKABE_ITO["vermillion"]

WIDTH_IN = 10.0  # full report column at 110 dpi
HALF_WIDTH_IN = 5.4  # two figures side by side, each above 480 px

_RC: dict[str, Any] = {
    "font.size": 10.5,
    "axes.titlesize": 11,
    "axes.labelsize": 10.5,
    "xtick.labelsize": 9.5,
    "ytick.labelsize": 9.5,
    "legend.fontsize": 9,
    "legend.frameon": False,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "lines.linewidth": 1.3,
    "figure.dpi": 110,
    "savefig.dpi": 110,
}


def controller_colour(name: str) -> str:
    """The colour of controller ``name`` (the same in every figure and every run)."""
    base = str(name).split("/")[-1]
    if base in CONTROLLER_COLOURS:
        return CONTROLLER_COLOURS[base]
    return _SPARE[zlib.crc32(base.encode()) % len(_SPARE)]


def pyplot() -> Any:
    """matplotlib.pyplot on the Agg backend, with qsls's style applied."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt
    from cycler import cycler

    matplotlib.rcParams.update(_RC)  # type: ignore[arg-type]
    matplotlib.rcParams["axes.prop_cycle"] = cycler(color=list(CYCLE))
    return plt


def subplots(
    nrows: int = 1, ncols: int = 1, *, width: float = WIDTH_IN, height: float = 4.0, **kw: Any
) -> tuple[Any, Any]:
    """``plt.subplots`` in qsls's style with constrained layout (legends outside the axes are
    given room); always returns a 2-D array of axes."""
    plt = pyplot()
    kw.setdefault("layout", "constrained")
    return plt.subplots(nrows, ncols, figsize=(width, height), squeeze=False, **kw)


def legend_right(ax: Any, **kw: Any) -> Any:
    """A legend beside the axes (off the data)."""
    kw.setdefault("loc", "upper left")
    kw.setdefault("bbox_to_anchor", (1.01, 1.0))
    kw.setdefault("borderaxespad", 0.0)
    return ax.legend(**kw)


def legend_below(fig: Any, handles: Any = None, labels: Any = None, ncol: int = 4) -> Any:
    """One legend for the whole figure, under the axes (off the data)."""
    if handles is None:
        seen: dict[str, Any] = {}
        for ax in fig.axes:
            for h, label in zip(*ax.get_legend_handles_labels(), strict=True):
                if not label.startswith("_"):
                    seen.setdefault(label, h)
        labels, handles = list(seen), list(seen.values())
    if not handles:
        return None
    return fig.legend(handles, labels, loc="outside lower center", ncol=ncol)
