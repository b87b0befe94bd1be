"""The options of the bound check (``qsls evaluate``, and the ``evaluate:`` section of a config
file with :class:`~qsls.pipeline.evaluate.section.EvaluateSection`), apart from the stage: this
module imports only pydantic and the core, so ``qsls run`` validates a run config without
loading pandas. :mod:`qsls.pipeline.evaluate.bound` re-exports it."""

from __future__ import annotations

from qsls.pipeline.core.config import Options


class EvaluateOptions(Options):
    """Options of the bound check (``qsls evaluate``)."""

    smooth_s: float = 1.0
    """Time constant (s) of the first-order average drawn over ``||e||`` in the figures
    (the paper's figure used 1 s); 0 draws the raw signal only. Numbers are never smoothed."""
    state_scale: tuple[float, float, float, float, float, float] | None = None
    """Per-coordinate weights of the state distance; must equal the error model's (its
    S-slope is a slope in that norm), which is the default."""
    flown_by: str | None = None
    """The controller (by name) that flew the given flights: the theorem is checked on its
    rows; every other row, and every row when unset, checks the premise only."""
    figures: bool = True
    """Write the PNG figures."""
    max_figure_flights: int = 12
    """At most this many flights get a panel in the figures (all are in the tables)."""
