"""The ``evaluate:`` section of a config file, read the same way by ``qsls evaluate --config``
and by ``qsls run``: the bound check's options (:class:`EvaluateOptions`) and, under ``fly:``,
the options of the flights flown by the controllers (:class:`FlyOptions`, which inherit the
section's own keys: ``figures: false`` beside ``fly:`` holds for both)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from qsls.pipeline.core.config import merge, validate
from qsls.pipeline.evaluate.options import EvaluateOptions, FlyOptions


class EvaluateSection(EvaluateOptions):
    """``evaluate:``: the bound check's options, plus ``fly`` for ``qsls fly``."""

    fly: dict[str, Any] | None = None
    """Options of ``qsls fly`` (the run's ``fly`` stage) over the section's own:
    seeds, duration, conditions, jobs, sim, ... (:class:`FlyOptions`); absent: the run flies
    nothing."""

    def _own(self) -> dict[str, Any]:
        return self.model_dump(exclude={"fly"}, exclude_unset=True)

    def bound(self) -> EvaluateOptions:
        """The bound check's options."""
        return EvaluateOptions.model_validate(self._own())

    def flying(
        self,
        overrides: Mapping[str, Any] | None = None,
        source: str = "options",
        base_sim: Mapping[str, Any] | None = None,
    ) -> FlyOptions:
        """The flying options: the section's keys, then ``fly``'s, then ``overrides`` (the
        command line's); ``base_sim`` (a run's ``simulate:`` section) is laid under their
        ``sim``, as under the calibration's; errors name ``source``."""
        data = merge(merge(self._own(), self.fly or {}), overrides or {})
        if base_sim:
            data["sim"] = merge(dict(base_sim), data.get("sim") or {})
        return validate(FlyOptions, data, source)
