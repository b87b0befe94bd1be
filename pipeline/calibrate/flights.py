"""The calibration's flights (docs/calibration.md#the-packages-shape): what each flies, flying
them, and the tick logs the scores read, from whichever source they come.

- Simulated: a :class:`Job` per flight (the candidate, its perception condition, its seed, its
  draw from the condition family and, for a range flight, the reference's offset), flown on the
  pool or Dask (:func:`fly_jobs`); each tick log is kept in the output
  (``flights/<name>/ticks.parquet``) and named in the record by its sha256 (:func:`keep`).
- Recorded (docs/vehicle.md): the user's flights (:mod:`qsls.pipeline.calibrate.recorded`),
  each proved flown by one candidate (:func:`assign`), the conditions the record states read
  from their logs (:func:`recorded_conditions`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.calibrate.options import CalibrateOptions
from qsls.pipeline.calibrate.recorded import RecordedFlight
from qsls.pipeline.control.artifacts import FlightEvidence
from qsls.pipeline.core.artifacts import StageWriter, sha256_file
from qsls.pipeline.core.config import merge
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.progress import Progress
from qsls.pipeline.core.ticks import TICKS_FILE, TickLog
from qsls.pipeline.core.workers import run_flights
from qsls.pipeline.evaluate.conditions import draw
from qsls.pipeline.evaluate.flownby import flown_by
from qsls.pipeline.sim.closedloop import fly
from qsls.pipeline.sim.options import SimOptions
from qsls.pipeline.sim.ticks import tick_log

PERCEPTION_ATTR = "perception"
"""The perception condition a calibration flight flew, kept in its tick log's metadata (under
the log's sha256, so ``qsls verify`` reads the condition from the evidence: docs/verify.md)."""
MIN_HEIGHT = 0.6
"""Lowest reference height of a range flight (m): lower, the circle's ground effect and the
floor-crash rule decide the flight, not perception."""
DT_TOLERANCE = 0.01
"""A recorded flight's tick may differ from the certificate's ``dt`` by this fraction (jitter)."""


# --------------------------------------------------------------------------- simulated
@dataclass(frozen=True)
class Job:
    """One flight of a candidate."""

    name: str
    controller: str
    folder: str
    condition: str
    seed: int
    role: str
    """``calibration`` (its score enters the quantile), ``range`` (its reference moved within
    the tube: it tests the premise out to ``rho*``, its score can only raise ``lambda_hat``) or
    ``validation`` (checked against the calibrated premise, never scored)."""
    sim: dict[str, Any]
    """The flight's simulation options (the run's, its condition's and its family draw)."""
    offset: tuple[float, float, float]
    """The reference's offset (a range flight's; zeros otherwise)."""
    sha256: str = ""
    """The flying controller's ``controller.npz`` sha256, stamped on its tick log."""


def fly_job(job: Job) -> TickLog:
    """Fly ``job`` (no bag: the tick log is what the scores read)."""
    ref = dict(job.sim.get("reference") or {})
    cx, cy = ref.get("center", (0.0, 0.0))
    over: dict[str, Any] = {
        "seed": job.seed,
        "controller": {"kind": job.folder},
        "vio": {"perception": job.condition},
    }
    if any(job.offset):
        over["reference"] = {
            "center": [float(cx) + job.offset[0], float(cy) + job.offset[1]],
            "height": float(ref.get("height", 1.0)) + job.offset[2],
        }
    opts = SimOptions.model_validate(merge(job.sim, over))
    return tick_log(fly(opts), job.sha256)


def offsets(seed: int, tube: float, height: float = 1.0) -> tuple[float, float, float]:
    """The reference offset of flight ``seed`` in a tube of radius ``tube``: uniform in the
    horizontal disc of radius ``tube``, the height uniform within ``tube / 2`` but never
    below :data:`MIN_HEIGHT` (its own seeded stream)."""
    if tube <= 0:
        return (0.0, 0.0, 0.0)
    rng = np.random.default_rng([seed, 7919])
    r = tube * math.sqrt(rng.uniform())
    th = rng.uniform(0, 2 * math.pi)
    dz = rng.uniform(max(-tube / 2, MIN_HEIGHT - height), tube / 2)
    return (r * math.cos(th), r * math.sin(th), dz)


@dataclass(frozen=True)
class Flyer:
    """Who flies a role's flights: a folder and its controller's sha256 per candidate name."""

    folder: Callable[[str, str], Path]
    """``(condition, candidate) -> controller folder``."""
    sha256: Callable[[str], str]


def jobs(
    role: str,
    seeds: Sequence[int],
    names: Sequence[str],
    flyer: Flyer,
    options: CalibrateOptions,
    sim: dict[str, Any],
) -> list[Job]:
    """Every candidate's ``role`` flights in every condition, one per seed, each with its draw
    from the condition family (and a range flight's offset)."""
    height = float(options.sim.reference.height)
    out = []
    for cond in options.conditions:
        for name in names:
            for s in seeds:
                off = offsets(s, options.tube, height) if role == "range" else (0.0, 0.0, 0.0)
                out.append(
                    Job(
                        name=f"{role}_{cond}_{name}_s{s}",
                        controller=name,
                        folder=str(flyer.folder(cond, name).resolve()),
                        condition=cond,
                        seed=s,
                        role=role,
                        sim=merge(sim, draw(options.family, s, sim)),
                        offset=off,
                        sha256=flyer.sha256(name),
                    )
                )
    return out


def fly_jobs(
    todo: Sequence[Job], options: CalibrateOptions, progress: Progress, what: str
) -> list[TickLog]:
    """Fly ``todo`` on the pool (or the options' Dask scheduler), in order."""
    return run_flights(fly_job, todo, options, progress, what, "calibration")


def keep(w: StageWriter, j: Job, tk: TickLog) -> FlightEvidence:
    """Write ``j``'s tick log (``flights/<name>/ticks.parquet``) and name it with its sha256."""
    df = tk.frame()
    df.attrs[PERCEPTION_ATTR] = j.condition
    name = f"flights/{j.name}/{TICKS_FILE}"
    sha = sha256_file(w.write_parquet(name, df))
    return FlightEvidence(flight=j.name, role=j.role, ticks=name, sha256=sha, seed=j.seed)


# --------------------------------------------------------------------------- recorded
def check_dt(flights: Sequence[RecordedFlight], folder: Path, dt: float) -> None:
    """Refuse a flight whose controller ticked at another rate than ``folder``'s."""
    for f in flights:
        have = float(f.conditions["dt_s"])
        if abs(have - dt) > DT_TOLERANCE * dt:
            raise InputError(
                f"recorded flight {f.folder}: its controller ticked every {have:.4g} s, "
                f"{folder.name} is synthesized for dt {dt:g} s: not flown by this controller"
            )


def assign(flights: Sequence[RecordedFlight], folders: Sequence[Path]) -> dict[str, str]:
    """Which candidate flew each flight (:func:`~qsls.pipeline.evaluate.flownby.flown_by`); a
    flight none of them flew is refused in one line, with the first candidate's reason."""
    owners: dict[str, str] = {}
    for f in flights:
        why = ""
        for folder in folders:
            p = flown_by(f.log, folder, f.mass, f.stamps)
            if p.flown:
                owners[f.name] = folder.name
                break
            why = why or f"{folder.name}: {p.reason}"
        if f.name not in owners:
            raise InputError(
                f"recorded flight {f.folder} ({f.role}): not flown by "
                f"{'any candidate' if len(folders) > 1 else 'this controller'} ({why})"
            )
    return owners


def recorded_conditions(
    flights: Sequence[RecordedFlight], condition: str, estimator: str = ""
) -> dict[str, Any]:
    """What the certificate states of its calibration flights (their logs' conditions); the
    estimator is the estimate's topic unless named (the stand-in's: its simulated one)."""
    first = flights[0].conditions
    hover = _span([f.conditions["vehicle"].get("hover_thrust") for f in flights])
    return {
        "source": "standin" if estimator else "recorded",
        "perception": condition,
        "estimator": estimator or first["estimator"],
        "estimate_topic": first["estimator"],
        "truth": first["truth"],
        "dt_s": first["dt_s"],
        "vehicle": {**first["vehicle"], "hover_thrust": hover},
        "frame": first["frame"],
        "reference": _reference_family(flights),
        "duration_s": max(float(f.conditions["duration_s"]) for f in flights),
    }


def _span(values: list[Any]) -> list[float] | None:
    """``[low, high]`` of the numbers among ``values`` (None where there are none)."""
    nums = [float(v) for v in values if isinstance(v, int | float)]
    return [min(nums), max(nums)] if nums else None


def _reference_family(flights: Sequence[RecordedFlight]) -> dict[str, list[float]]:
    """The range of each reference number over the flights (``[low, high]``): the references
    the calibration flew (:func:`qsls.pipeline.ingest.ticks.reference_summary`)."""
    refs = [f.conditions["reference"] for f in flights if f.conditions.get("reference")]
    keys = sorted({k for r in refs for k in r})
    return {k: [min(r[k] for r in refs), max(r[k] for r in refs)] for k in keys}


def recorded_evidence(f: RecordedFlight, root: Path) -> FlightEvidence:
    """A recorded flight's tick log and its sha256 (docs/verify.md): named relative to the
    output where it lies inside it (a stand-in's), else by its absolute path."""
    ticks = (f.folder / TICKS_FILE).resolve()
    where = ticks.relative_to(root.resolve()) if ticks.is_relative_to(root.resolve()) else ticks
    return FlightEvidence(
        flight=f.name,
        role=f.role,
        ticks=where.as_posix(),
        sha256=sha256_file(ticks),
        log_sha256=f.log_sha256 or None,
    )
