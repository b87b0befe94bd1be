"""``certificate.yaml``'s ``calibration`` record (:class:`Calibration`, the flights behind it
:class:`FlightEvidence`) and what keeps a record from backing a ``certified`` status
(:func:`record_problems`, docs/calibration.md, docs/verify.md)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from pydantic import BaseModel, ConfigDict, field_validator

from qsls.pipeline.control.conformal import MAX_ALPHA, MIN_FLIGHTS, Method, calibrated_quantile
from qsls.pipeline.control.monitor_record import MonitorCalibration


class FlightEvidence(BaseModel):
    """One flight behind a calibration: its tick log and that log's sha256 (docs/verify.md).
    ``qsls verify`` re-reads the log, checks the hash and recomputes the flight's score."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    flight: str
    """The flight's name (its row in ``scores.parquet`` / ``validation.parquet``)."""
    role: str
    """``calibration``, ``range`` or ``validation``."""
    ticks: str
    """The tick log: relative to the calibration output (``flights/<name>/ticks.parquet``), or
    the recorded flight's own ``ticks.parquet`` in its ingest folder (absolute)."""
    sha256: str
    """sha256 of the tick log's bytes."""
    seed: int | None = None
    """A simulated flight's seed (None for a recorded flight)."""
    log_sha256: str | None = None
    """A recorded flight's vehicle log (what ``logs`` lists for the calibration flights)."""

    @field_validator("role")
    @classmethod
    def _role(cls, v: str) -> str:
        if v not in ("calibration", "range", "validation"):
            raise ValueError(f"role {v!r} is not calibration, range or validation")
        return v


class Calibration(BaseModel):
    """``certificate.yaml``'s ``calibration``: the flights the premise was calibrated on and
    what it promises for the next one (docs/calibration.md, :mod:`qsls.pipeline.control.calibration`)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    flights: int
    """Calibration flights, flown by this controller under ``conditions``."""
    alpha: float
    """The stated probability that a new flight of ``conditions`` breaks the calibrated premise."""
    confidence: float | None
    """``1 - delta`` of a PAC statement (over the draw of the calibration flights); None for
    split conformal (a marginal statement)."""
    method: str
    conditions: dict[str, Any]
    duration_s: float
    seeds: list[int]
    scores: list[float]
    """Each flight's ``lambda_f``: the smallest premise inflation it satisfies."""
    design_seeds: list[int] = []
    """Seeds of the design flights (the fit's simulated flights, and any given): no
    calibration seed is among them."""
    lambda_hat: float
    """The calibrated inflation: the score of rank ``rank`` (ascending)."""
    rank: int
    tested_range: float
    """The largest ``dist(x_k)`` the calibration flights reached."""
    nominal: dict[str, float | None]
    """The design premise before inflation."""
    parts: dict[str, float]
    """The largest ratio of each premise quantity over the calibration flights."""
    tolerances: dict[str, float]
    """Per premise quantity: the factor it alone could grow by before the condition fails."""
    holds: bool
    """The robustness condition under the inflated premise, on the fixed taps."""
    range_flights: int = 0
    """Range flights (the reference offset within a tube): scored on the perception premise
    only, their calibrated score can only raise ``lambda_hat``."""
    range_scores: list[float] = []
    evidence_seeds: list[int] = []
    """Every seed a flight of this calibration flew (calibration, range and validation): a
    flight on one of them is that flight again, no fresh evidence (``qsls fly`` refuses it)."""
    logs: list[str] = []
    """Recorded calibration flights (docs/vehicle.md): the sha256 of each flight's vehicle log,
    in the order of ``scores`` (a seed's place: empty for simulated flights)."""
    evidence: list[FlightEvidence] = []
    """Every flight's tick log with its sha256 (calibration and range flights in the order of
    ``scores`` and ``range_scores``, then the validation flights): what ``qsls verify``
    recomputes the record from (docs/verify.md). Empty in a record written before it existed."""
    monitor: MonitorCalibration | None = None
    """The innovation monitor's mode, false-trip rate and quantile of its calibration flights'
    statistics (docs/monitor.md#the-calibrated-mode); None: sound, none recorded."""

    @field_validator("tested_range", "duration_s", "alpha")
    @classmethod
    def _finite(cls, v: float) -> float:
        # NaN compares false with everything: a NaN here would pass every later comparison
        if not math.isfinite(v) or v < 0:
            raise ValueError(f"{v} is not a finite non-negative number")
        return v


def record_problems(
    *,
    flights: int,
    alpha: float,
    method: str,
    confidence: float | None,
    scores: Sequence[float],
    range_scores: Sequence[float],
    lambda_hat: float,
    holds: bool,
    rho_star: float | None,
    tested_range: float | None,
    shared_seeds: Sequence[int] = (),
) -> list[str]:
    """What keeps a recorded calibration from backing a ``certified`` status (empty when
    nothing does): at least :data:`MIN_FLIGHTS` flights, ``alpha <= MAX_ALPHA``, ``lambda_hat``
    at least the calibrated quantile of the recorded scores (and of the range flights'), the
    condition holding under it, the premise tested out to ``rho*``, and no calibration seed
    among the design flights' (``shared_seeds``). Read whenever a
    certificate is loaded, so a hand-edited record cannot claim what its flights do not."""
    why = []
    if flights < MIN_FLIGHTS or len(scores) != flights:
        why.append(f"{flights} calibration flights with {len(scores)} scores (needs {MIN_FLIGHTS})")
    if alpha > MAX_ALPHA:
        why.append(f"alpha {alpha:g} > {MAX_ALPHA:g}")
    m: Method = "pac" if method == "pac" else "conformal"
    # 1 - (1 - delta) may come back a hair below delta; never refuse on that rounding
    delta = 1.0 - confidence + 1e-12 if confidence is not None else 0.05
    lam = max(
        calibrated_quantile(scores, alpha, m, delta),
        calibrated_quantile(range_scores, alpha, m, delta) if len(range_scores) else 0.0,
    )
    if not lambda_hat >= lam * (1 - 1e-12):
        why.append(f"lambda_hat {lambda_hat:.6g} below its scores' quantile {lam:.6g}")
    if not holds:
        why.append("the condition fails under the calibrated premise")
    if rho_star is None or tested_range is None or tested_range < rho_star * (1 - 1e-9):
        why.append(f"tested to {tested_range} < rho* {rho_star}")
    if len(shared_seeds):
        why.append(f"calibration seeds {list(shared_seeds)[:5]} are design flights' seeds")
    return why
