"""The options of the calibration (``qsls calibrate``, and the ``calibrate:`` section of a run
config), apart from the stage: this module imports only pydantic, the core and the other stages'
light option modules, so ``qsls run`` validates a run config without loading pandas
(docs/calibration.md)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, field_validator, model_validator

from qsls.pipeline.core.config import Duration, FlightCount, Options, Seed
from qsls.pipeline.core.errors import ConfigError
from qsls.pipeline.core.workers import PoolOptions
from qsls.pipeline.evaluate.conditions import ConditionFamily
from qsls.pipeline.sim.options import Perception, SimOptions

Method = Literal["conformal", "pac"]


class RecordedFlights(Options):
    """Recorded flights of the user's vehicle (ingest folders with a tick log, ``qsls ingest
    LOG --mass KG``) by role, in place of simulated ones (docs/vehicle.md)."""

    calibration: list[Path] = Field(default_factory=list)
    """Calibration flights (ingest folders, or folders of them; on the command line repeated
    or comma-separated), each proved flown by the candidate from its log."""
    range: list[Path] = Field(default_factory=list)
    """Range flights (as ``calibration``): the reference moved away from the design's, scored
    without the reference's term."""
    validation: list[Path] = Field(default_factory=list)
    """Fresh flights (as ``calibration``) checked against the calibrated premise."""

    @property
    def by_role(self) -> dict[str, list[Path]]:
        """The folders by role, in the order calibration, range, validation."""
        return {"calibration": self.calibration, "range": self.range, "validation": self.validation}

    @property
    def paths(self) -> list[Path]:
        """Every folder given, role by role (:attr:`by_role`)."""
        return [p for ps in self.by_role.values() for p in ps]

    @property
    def given(self) -> bool:
        return bool(self.paths)


class MonitorOptions(Options):
    """Which thresholds the calibrated certificate's innovation monitor flies
    (docs/monitor.md#the-calibrated-mode)."""

    mode: Literal["sound", "calibrated"] = "sound"
    """``sound``: the premise's bound (a trip proves the premise broken); ``calibrated``: the
    conformal quantile of the calibration flights' window statistics (earlier catches, at a
    stated false-trip rate)."""
    false_trip_rate: float = Field(0.1, gt=0, lt=1)
    """``calibrated``: the probability that a next flight of the calibration's conditions
    trips the window sums (the quantile is recorded at this rate in either mode)."""


class CalibrateOptions(PoolOptions):
    """Options of ``qsls calibrate`` (the run's ``calibrate:`` section): each candidate flies
    its own calibration flights, then fresh validation flights (docs/calibration.md)."""

    flights: FlightCount = Field(20, ge=1)
    """Calibration flights per candidate and condition (19 at least for ``certified``); given
    as ingest folders instead of a number, the recorded calibration flights (``recorded``)."""
    validation: FlightCount = 20
    """Validation flights per candidate and condition (fresh seeds, used for nothing else)."""
    alpha: float = Field(0.1, gt=0, lt=1)
    """The stated probability that a new flight breaks the calibrated premise."""
    method: Method = "conformal"
    """``conformal``: marginal coverage ``1 - alpha``; ``pac``: coverage ``1 - alpha`` with
    confidence ``1 - delta`` over the calibration draw."""
    delta: float = Field(0.05, gt=0, lt=1)
    """``1 - confidence`` of the ``pac`` statement."""
    seed: Seed = 1000
    """First calibration seed (seeds ``seed .. seed + flights - 1``)."""
    validation_seed: Seed = 2000
    """First validation seed."""
    conditions: list[Perception] = Field(
        default_factory=lambda: ["regular"],  # type: ignore[arg-type]
        min_length=1,
    )
    """Perception conditions: one calibrated certificate per candidate and condition."""
    family: ConditionFamily = ConditionFamily()
    """The conditions each calibration, range and validation flight draws from (the vehicle's
    true mass, the reference's radius, period, height and centre); the certificate states the
    family and every flight is checked against it (docs/calibration.md, Conditions as a
    stated family). Default: one vehicle on one reference."""
    duration: Duration = 20.0
    """Seconds per flight."""
    range_flights: FlightCount = 0
    """Range flights per candidate and condition: the candidate flies the design reference
    moved by a random offset within ``tube``, so the flights reach distances from the training
    states toward ``rho*``; they are scored on every premise quantity but the reference's
    distance (dense part, disturbance, outlier count: the reference's offset is the point), and
    the certificate takes the larger of the two calibrated inflations (docs/calibration.md,
    Tested range)."""
    tube: float = Field(0.0, ge=0)
    """Radius (m) of the range flights' offsets: horizontal, uniform in the disc; the height
    uniform within ``tube / 2``."""
    range_seed: Seed = 3000
    """First range-flight seed."""
    controllers: list[str] | None = None
    """Candidate controller names; default: every robust controller whose design check passed."""
    sim: SimOptions = SimOptions()
    """Vehicle, reference, VIO emulator and crash limits (``qsls run`` lays its ``simulate:``
    section here); seed, controller, perception and duration are set per flight."""
    source: Literal["simulated", "standin"] = "simulated"
    """Who flies the calibration, range and validation flights: ``simulated`` (the Python
    realization in the simulator, its tick log kept), or ``standin``: the stand-in for a PX4
    vehicle (the exported C behind the PX4 interface, each flight a ULog ingested with the
    vehicle's mass and calibrated as a recorded flight; docs/vehicle.md)."""
    standin_log: Literal["ulog", "mavros"] = "ulog"
    """With ``source: standin``, how the stand-in vehicle logs each flight: a PX4 ULog, or a
    ROS1 bag as a mavros user records it (docs/vehicle.md)."""
    monitor: MonitorOptions = MonitorOptions()
    """The innovation monitor's mode and false-trip rate (``mode: calibrated`` for thresholds
    at the calibration flights' conformal quantile; docs/monitor.md#the-calibrated-mode)."""
    recorded: RecordedFlights = RecordedFlights()
    """Recorded flights by role (``calibration``, ``range``, ``validation``; a plain list is the
    calibration flights); given, no flight is simulated (docs/vehicle.md)."""

    @model_validator(mode="before")
    @classmethod
    def _flights_as_folders(cls, data: object) -> object:
        """``flights`` given as folders (``qsls calibrate --flights F1 F2``) are recorded
        calibration flights."""
        if isinstance(data, dict) and isinstance(data.get("flights"), list | tuple):
            given = [str(f) for f in data["flights"]]
            rec = data.get("recorded") or {}
            rec = {"calibration": rec} if isinstance(rec, list | tuple | str) else dict(rec)
            rec["calibration"] = [*rec.get("calibration", []), *given]
            data = {**data, "flights": max(1, len(given)), "recorded": rec}
        return data

    @field_validator("recorded", mode="before")
    @classmethod
    def _a_list_is_calibration(cls, v: object) -> object:
        return {"calibration": v} if isinstance(v, list | tuple | str) else v

    design_seeds: list[Seed] = Field(default_factory=list)
    """Seeds of the design flights (``qsls run`` fills them in): a calibration or validation
    seed among them is refused, as is a validation seed among the calibration ones."""

    def seed_lists(self) -> tuple[list[int], list[int]]:
        """Calibration and validation seeds, refused (``ConfigError``) where they meet a design
        seed or each other: a design choice made on a flight would then be tested on it."""
        calib = list(range(self.seed, self.seed + self.flights))
        valid = list(range(self.validation_seed, self.validation_seed + self.validation))
        design = set(self.design_seeds)
        if self.range_flights and self.tube <= 0:
            raise ConfigError(
                "--range-flights needs --tube > 0, the offsets' radius in m (calibrate.range_flights "
                "and calibrate.tube in a config)"
            )
        ranged = list(range(self.range_seed, self.range_seed + self.range_flights))
        for what, key, seeds in (
            ("calibration", "seed", calib),
            ("validation", "validation_seed", valid),
            ("range", "range_seed", ranged),
        ):
            shared = sorted(design.intersection(seeds))
            if shared:
                raise ConfigError(
                    f"{what} seeds {shared[:5]} are design flights' seeds: a certificate must be "
                    f"calibrated and validated on flights its design never saw; move "
                    f"--{key.replace('_', '-')} past them (calibrate.{key} in a config)"
                )
        both = sorted(set(calib).union(ranged).intersection(valid))
        if both:
            raise ConfigError(
                f"validation seeds {both[:5]} are also calibration or range seeds: validation "
                "flights must be fresh; move --validation-seed past them "
                "(calibrate.validation_seed in a config)"
            )
        return calib, valid

    @property
    def flies_recorded(self) -> bool:
        """Whether the candidates are calibrated on recorded flights (the user's, or the
        stand-in vehicle's logs) rather than on flights the simulator keeps the tick logs of:
        the one rule of which path the stage (:func:`qsls.pipeline.calibrate.stage.calibrate`)
        takes."""
        return self.recorded.given or self.source == "standin"

    @property
    def flown_here(self) -> bool:
        """Whether qsls flies the flights itself (the simulator, or the stand-in vehicle), on
        seeds no design flight used, rather than reading the user's recorded ones."""
        return not self.recorded.given

    @property
    def range_seeds(self) -> list[int]:
        return list(range(self.range_seed, self.range_seed + self.range_flights))
