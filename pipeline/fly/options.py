"""The options of ``qsls fly`` (the run config's top-level ``fly:`` section), apart from the
stage: this module imports only pydantic, the core and the other stages' light option modules,
so ``qsls run`` validates a run config without loading pandas (docs/evaluation.md, Flying the
controllers)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal

from pydantic import Field, field_validator

from qsls.pipeline.core.config import (
    MAX_FLIGHTS,
    Duration,
    Seed,
    merge,
    read_section,
    read_yaml,
    validate,
)
from qsls.pipeline.core.errors import ConfigError
from qsls.pipeline.core.workers import PoolOptions
from qsls.pipeline.evaluate.options import CheckOptions
from qsls.pipeline.evaluate.section import FLY_MOVED
from qsls.pipeline.ingest.options import IngestOptions
from qsls.pipeline.sim.options import Perception, SimOptions

Vio = Literal["emulator", "camera"]


class FlyOptions(PoolOptions, CheckOptions):
    """Options of ``qsls fly``: the flights flown (pool: :class:`PoolOptions`) and the bound
    check's tables and figures of them (:class:`CheckOptions`)."""

    seeds: list[Seed] = Field(
        default_factory=lambda: [0, 1, 2], min_length=1, max_length=MAX_FLIGHTS
    )
    """Seeds of the VIO emulator (and of the log's noise); one flight per seed."""
    duration: Duration = 30.0
    """Seconds per flight."""
    conditions: list[Perception] = Field(
        default_factory=lambda: ["regular", "degraded"],  # type: ignore[arg-type]
        min_length=1,
    )
    """Perception conditions (the emulator's presets)."""
    vio: Vio | list[Vio] = "emulator"
    """Where each flight's estimate comes from: ``emulator`` (the VIO error model) or
    ``camera`` (a rendered camera, an IMU and an MSCKF; ``sim.vio.camera`` holds its
    parameters). A list (``camera,emulator``) flies every controller, seed and condition with
    each, paired by seed; the first is the primary (its tables as a single-estimator run
    writes them), every estimator's results also keyed by estimator (docs/evaluation.md)."""

    @field_validator("vio")
    @classmethod
    def _distinct_estimators(cls, v: Vio | list[Vio]) -> Vio | list[Vio]:
        if isinstance(v, list) and (not v or len(set(v)) < len(v)):
            raise ValueError("vio: give each estimator once, at least one")
        return v

    @property
    def estimators(self) -> tuple[Vio, ...]:
        """The estimators flown, the primary first."""
        return tuple(self.vio) if isinstance(self.vio, list) else (self.vio,)

    controllers: list[str] | None = None
    """Controller folder names to fly; default: the paper's four where given, else all."""
    se3: bool = True
    """Also fly RotorPy's SE3 controller (the training flights' controller)."""
    sim: SimOptions = SimOptions()
    """Vehicle, reference, VIO emulator, crash limits and the log's format (seed, duration,
    controller and perception are set per flight)."""
    ingest: IngestOptions = IngestOptions()
    """How each flight's bag is ingested (as a real one)."""
    track_threshold_m: float = Field(0.3, gt=0)
    """A controller 'tracks' when it does not crash and its tracking RMS is below this (m)."""
    tie_rel: float = Field(0.02, ge=0)
    """Relative difference below which two controllers' numbers count as a tie (findings)."""
    pd_z_control: bool | list[str] = False
    """Fly synthesized controllers with the PD's height (thrust) channel, pitch and roll
    staying theirs: ``true`` for every synthesized controller, or the list of those that do
    (the paper: the imitation controller only, ``[l1_robust_imitation]``, "for safety" on
    hardware and matched in simulation)."""

    def pd_z_for(self, controller: str) -> bool:
        """Whether ``controller`` flies with the PD's height channel (``pd_z_control``)."""
        z = self.pd_z_control
        return z if isinstance(z, bool) else controller in z

    keep_bags: bool = False
    """Keep every flight's simulate folder (bag, truth.json) under ``sims/``."""
    assured: bool = False
    """Also fly each controller that has an onboard monitor (a robust certificate, certified or
    relaxed) in runtime-assured mode: it flies until its monitor trips, then ``fallback``
    flies (docs/monitor.md, The fallback); beside the controller alone and PD alone, same
    seeds. Written to ``assured.parquet`` and the flights' tick logs."""
    fallback: Literal["pd", "hold"] = "pd"
    """The assured mode's fallback: ``pd``, the PD reference on the reference from the current
    estimate; ``hold``, PD holding the estimated position of the trip tick."""


def refuse_nested(data: Mapping[str, Any], source: str) -> None:
    """The one-line error (:data:`~qsls.pipeline.evaluate.section.FLY_MOVED`) for a config
    whose ``evaluate:`` section still holds ``fly:`` (one release; docs/run.md)."""
    evaluate = data.get("evaluate")
    if isinstance(evaluate, Mapping) and "fly" in evaluate:
        raise ConfigError(f"{source}: evaluate: 'fly': {FLY_MOVED}")


def flying(
    data: Mapping[str, Any] | None,
    overrides: Mapping[str, Any] | None = None,
    source: str = "options",
    base_sim: Mapping[str, Any] | None = None,
) -> FlyOptions:
    """The flying options: the ``fly:`` section ``data``, then ``overrides`` (the command
    line's), ``base_sim`` (a run's ``simulate:`` section) laid under their ``sim`` as under the
    calibration's; errors name ``source``."""
    merged = merge(dict(data or {}), overrides or {})
    if base_sim:
        merged["sim"] = merge(dict(base_sim), merged.get("sim") or {})
    return validate(FlyOptions, merged, source)


def load_fly_options(config: Path | None, overrides: Mapping[str, Any] | None = None) -> FlyOptions:
    """``qsls fly --config FILE``: the file's ``fly:`` section (else the whole file), then the
    command line's ``overrides``; a file whose ``evaluate:`` still holds ``fly:`` is refused
    (:func:`refuse_nested`)."""
    if config is not None:
        refuse_nested(read_yaml(config), str(config))
    return flying(read_section(config, "fly"), overrides, str(config or "options"))
