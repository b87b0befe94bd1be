"""The ``evaluate:`` section of a config file, read the same way by ``qsls evaluate --config``
and by ``qsls run``: the bound check's options (:class:`EvaluateOptions`). The flights flown by
the controllers have a top-level section of their own, ``fly:``
(:class:`qsls.pipeline.fly.options.FlyOptions`); an ``evaluate:`` that still holds ``fly:``
is refused with a one-line pointer (:data:`FLY_MOVED`, for one release)."""

from __future__ import annotations

from typing import Any

from pydantic import field_validator

from qsls.pipeline.evaluate.options import EvaluateOptions

FLY_MOVED = (
    "flying is a stage of its own now: move this mapping out of evaluate: to a top-level "
    "fly: section (with any smooth_s, state_scale, figures or max_figure_flights it took "
    "from evaluate:)"
)
"""The one-line pointer an old config (``evaluate: {fly: ...}``) gets, for one release."""


class EvaluateSection(EvaluateOptions):
    """``evaluate:``: the bound check's options."""

    fly: Any = None
    """Refused (:data:`FLY_MOVED`): the flying options are the top-level ``fly:`` section's."""

    @field_validator("fly")
    @classmethod
    def _fly_moved(cls, v: Any) -> Any:
        if v is not None:
            raise ValueError(FLY_MOVED)
        return v

    def bound(self) -> EvaluateOptions:
        """The bound check's options."""
        return EvaluateOptions.model_validate(self.model_dump(exclude={"fly"}, exclude_unset=True))
