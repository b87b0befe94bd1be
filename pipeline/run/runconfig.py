"""The run config of ``qsls run``: flights plus each stage's options (:class:`RunConfig`),
its models only, so that its resolution into each stage's options
(:mod:`qsls.pipeline.run.sections`) and the runner (:mod:`qsls.pipeline.run.runner`, which
reads the file and re-exports these) both import it without importing each other."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field, PrivateAttr, field_validator, model_validator

from qsls.pipeline.calibrate.options import CalibrateOptions
from qsls.pipeline.control.options import SweepSection, SynthOptions
from qsls.pipeline.core.artifacts import to_plain
from qsls.pipeline.core.config import Options, Seed
from qsls.pipeline.errormodel.options import FitOptions
from qsls.pipeline.evaluate.section import EvaluateSection
from qsls.pipeline.fly.options import FlyOptions
from qsls.pipeline.ingest.options import IngestOptions
from qsls.pipeline.sim.options import SimOptions


def plain_name(v: str, what: str) -> str:
    """``v`` when it is a plain folder name: not empty, no ``/`` or ``\\``, not starting
    with ``.`` (no ``..``, no hidden folder), no control character (a newline)."""
    if (
        not v
        or any(c in v for c in "/\\")
        or v.startswith(".")
        or any(ord(c) < 0x20 or ord(c) == 0x7F for c in v)
    ):
        raise ValueError(
            f"{what} must be a plain folder name (no '/', '\\', leading '.' or control "
            f"characters such as a newline), got {v!r}"
        )
    return v


class FlightSpec(Options):
    """One flight: simulated (``simulate`` options) or a real log (``sources`` / ``vio``+``truth``)."""

    name: str
    role: Literal["train", "heldout"] = "train"
    simulate: dict[str, Any] | None = None
    sources: list[str] = Field(default_factory=list)
    vio: str | None = None
    truth: str | None = None
    ingest: dict[str, Any] = Field(default_factory=dict)

    @field_validator("name")
    @classmethod
    def _safe_name(cls, v: str) -> str:
        return plain_name(v, "a flight name")

    @model_validator(mode="after")
    def _one_kind(self) -> FlightSpec:
        logged = [k for k in ("sources", "vio", "truth") if getattr(self, k)]
        if self.simulate is not None and logged:
            raise ValueError(
                f"flight '{self.name}' has both simulate: and {', '.join(logged)}: a flight is "
                f"either simulated or read from logs; remove one"
            )
        return self


class RunConfig(Options):
    """The run: flights plus each stage's options (the stage's own option names).

    Each stage section is the same section the stage command reads with ``--config``, typed
    by the model that command uses: ``simulate``
    :class:`~qsls.pipeline.sim.options.SimOptions`, ``ingest``
    :class:`~qsls.pipeline.ingest.options.IngestOptions`, ``fit``
    :class:`~qsls.pipeline.errormodel.options.FitOptions`, ``sweep``
    :class:`~qsls.pipeline.control.options.SweepSection` (with ``jobs``, ``scheduler``,
    ``wait_workers``), ``synth`` :class:`~qsls.pipeline.control.options.SynthOptions` (both
    with the config's ``problem:`` laid under them, :func:`~qsls.pipeline.core.config.with_shared`:
    the settings they share, stated once),
    ``evaluate`` :class:`~qsls.pipeline.evaluate.section.EvaluateSection` (the bound check;
    a ``fly:`` under it is refused with a pointer), ``fly``
    :class:`~qsls.pipeline.fly.options.FlyOptions` (the controllers flown, the run's
    ``simulate:`` laid under its ``sim``). These
    models live apart from their stages, so reading a run config loads no solver, pandas or
    simulator: a run with nothing to do imports nothing heavy.

    ``simulate`` and ``ingest`` are also the bases of the flights: a flight's own
    ``simulate:`` / ``ingest:`` is laid over the section as written (:meth:`written`; the
    flight's keys win, nested mappings merge) and the result is validated per flight when
    planned (:func:`qsls.pipeline.run.sections.resolve_sections`), its errors naming the
    flight. The base must be valid on its own, as it is for
    ``qsls simulate --config`` / ``qsls ingest --config`` reading the same file: a base
    ``vio: {outlier_min: 2}`` is refused (above the default ``outlier_max``, 1) even when
    every flight raises ``outlier_max``; such a pair belongs in the flights."""

    name: str
    seed: Seed = 0
    out: str | None = None
    stages: (
        list[
            Literal[
                "simulate",
                "ingest",
                "fit",
                "sweep",
                "synth",
                "calibrate",
                "evaluate",
                "fly",
                "report",
            ]
        ]
        | None
    ) = None
    simulate: SimOptions = Field(default_factory=SimOptions)
    flights: list[FlightSpec]
    ingest: IngestOptions = Field(default_factory=IngestOptions)
    fit: FitOptions = Field(default_factory=FitOptions)
    sweep: SweepSection | None = None
    synth: SynthOptions | None = None
    calibrate: CalibrateOptions | None = None
    """Calibration and validation flights of the candidates (docs/calibration.md); the run's
    ``simulate:`` section is laid under its ``sim``."""
    evaluate: EvaluateSection | None = None
    fly: FlyOptions | None = None
    """The controllers flown side by side (``qsls fly``, docs/evaluation.md); the run's
    ``simulate:`` section is laid under its ``sim``. Absent: the run flies nothing."""
    report: bool = True
    _given: dict[str, Any] | None = PrivateAttr(None)

    @field_validator("name")
    @classmethod
    def _safe_name(cls, v: str) -> str:
        return plain_name(v, "the run name")

    def written(self, key: str) -> Any:
        """Section ``key`` as it was written: the file's mapping when the config was read
        (:func:`qsls.pipeline.run.runner.load_run_config`), else the keys set on the model; the
        default when absent."""
        if self._given is not None:
            return self._given.get(key, DEFAULTS[key])
        section = getattr(self, key)
        return (
            DEFAULTS[key]
            if section is None
            else section.model_dump(mode="json", exclude_unset=True)
        )

    def record(self) -> dict[str, Any]:
        """The config as plain data, its typed sections as they were written (the run's
        ``run.json`` and the plan's fingerprint: a default added to an options model does
        not make every run plan anew)."""
        plain = to_plain(self.model_dump(mode="json", exclude=set(SECTIONS)))
        return {
            k: (to_plain(self.written(k)) if k in SECTIONS else plain[k])
            for k in type(self).model_fields
        }


SECTIONS = ("simulate", "ingest", "fit", "sweep", "synth", "calibrate", "evaluate", "fly")
"""The typed stage sections of a run config (each validated with its stage's name in errors)."""
MODELS: dict[str, type[Options]] = {
    "simulate": SimOptions, "ingest": IngestOptions, "fit": FitOptions, "sweep": SweepSection,
    "synth": SynthOptions, "calibrate": CalibrateOptions, "evaluate": EvaluateSection,
    "fly": FlyOptions,
}  # fmt: skip
"""Each section's model: the one its stage command reads with ``--config``."""
DEFAULTS: dict[str, Any] = {
    "simulate": {}, "ingest": {}, "fit": {}, "sweep": None, "synth": None, "calibrate": None,
    "evaluate": None, "fly": None,
}  # fmt: skip
