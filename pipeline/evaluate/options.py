"""The options of the bound check (``qsls evaluate``, and the ``evaluate:`` section of a config
file with :class:`~qsls.pipeline.evaluate.section.EvaluateSection`), apart from the stage: this
module imports only pydantic, the core and the other stages' light option modules, so
``qsls run`` validates a run config without loading pandas. :mod:`qsls.pipeline.evaluate.stage`
reads them; the flying options (:mod:`qsls.pipeline.fly.options`) share
:class:`CheckOptions`."""

from __future__ import annotations

from pydantic import Field

from qsls.pipeline.core.config import Options


class CheckOptions(Options):
    """What the bound check's tables and figures read, whoever flew the flights: ``qsls
    evaluate`` (:class:`EvaluateOptions`) and ``qsls fly``
    (:class:`qsls.pipeline.fly.options.FlyOptions`)."""

    smooth_s: float = 1.0
    """Time constant (s) of the first-order average drawn over ``||e||`` in the bound check's
    figures (the paper's figure used 1 s; ``qsls fly`` draws the raw signal); 0 draws the raw
    signal only. Numbers are never smoothed."""
    state_scale: tuple[float, float, float, float, float, float] | None = None
    """Per-coordinate weights of the state distance; must equal the error model's (its
    S-slope is a slope in that norm), which is the default."""
    figures: bool = True
    """Write the PNG figures."""
    max_figure_flights: int = Field(12, ge=0, le=1000)
    """At most this many flights get a panel in the figures (all are in the tables)."""


class EvaluateOptions(CheckOptions):
    """Options of the bound check (``qsls evaluate``)."""

    flown_by: str | None = None
    """The controller (by name) that flew the given flights: the theorem is checked on its
    rows; every other row, and every row when unset, checks the premise only."""
