"""The options of the bound check (``qsls evaluate``, and the ``evaluate:`` section of a config
file with :class:`~qsls.pipeline.evaluate.section.EvaluateSection`), apart from the stage: this
module imports only pydantic, the core and the other stages' light option modules, so
``qsls run`` validates a run config without loading pandas. :mod:`qsls.pipeline.evaluate.bound`
and :mod:`qsls.pipeline.evaluate.fly` re-export them."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator

from qsls.pipeline.core.config import Options
from qsls.pipeline.ingest.options import IngestOptions
from qsls.pipeline.sim.options import SimOptions


class EvaluateOptions(Options):
    """Options of the bound check (``qsls evaluate``)."""

    smooth_s: float = 1.0
    """Time constant (s) of the first-order average drawn over ``||e||`` in the bound check's
    figures (the paper's figure used 1 s; ``--fly`` draws the raw signal); 0 draws the raw
    signal only. Numbers are never smoothed."""
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


Vio = Literal["emulator", "camera"]


class FlyOptions(EvaluateOptions):
    """Options of ``qsls evaluate --fly`` (and those of the bound check)."""

    seeds: list[int] = Field(default_factory=lambda: [0, 1, 2], min_length=1)
    """Seeds of the VIO emulator (and of the log's noise); one flight per seed."""
    duration: float = Field(30.0, gt=0)
    """Seconds per flight."""
    conditions: list[Literal["regular", "degraded"]] = Field(
        default_factory=lambda: ["regular", "degraded"],  # type: ignore[arg-type]
        min_length=1,
    )
    """Perception conditions (the emulator's presets)."""
    vio: Vio | list[Vio] = "emulator"
    """Where each flight's estimate comes from: the VIO emulator or the camera loop (a
    rendered camera, an IMU and an MSCKF: ``sim.vio.camera`` holds its parameters). A list
    (``[camera, emulator]``) flies every controller, seed and condition with each estimator;
    the first is the stage's primary (its tables as a single-estimator run writes them) and
    every estimator's results are also keyed by estimator (docs/evaluation.md)."""

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
    jobs: int = Field(0, ge=0)
    """Flights in parallel (process pool); 0 = all cores, 1 = in this process."""
    sim: SimOptions = SimOptions()
    """Vehicle, reference, VIO emulator, crash limits and the log's format (seed, duration,
    controller and perception are set per flight)."""
    ingest: IngestOptions = IngestOptions()
    """How each flight's bag is ingested (as a real one)."""
    track_threshold_m: float = Field(0.3, gt=0)
    """A controller 'tracks' when it does not crash and its tracking RMS is below this (m)."""
    tie_rel: float = Field(0.02, ge=0)
    """Relative difference below which two controllers' numbers count as a tie (findings)."""
    pd_z_control: bool = False
    """Fly the synthesized controllers with the PD's height (thrust) channel, as the paper
    did in simulation and on hardware "for safety"; pitch and roll stay theirs."""
    keep_bags: bool = False
    """Keep every flight's simulate folder (bag, truth.json) under ``sims/``."""
