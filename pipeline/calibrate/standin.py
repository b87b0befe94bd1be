"""The stand-in vehicle's calibration flights (docs/vehicle.md, docs/simulation.md#the-px4-stand-in).

``calibrate.source: standin`` flies a candidate's calibration, range and validation flights
the way a user's vehicle would, so the recorded-flights loop runs and is tested without one:
the EXPORTED C controller (compiled, through ctypes; ``controller.backend: c``) behind the
PX4 interface (an attitude setpoint and a normalized thrust, the estimate read by its arrival
time), each flight written as the ULog PX4 would write (``flight.ulg``; or, with
``standin_log: mavros``, the ROS1 bag a mavros user records, ``flight.bag``), then ingested
like any vehicle's log with the vehicle's mass (and, for a bag, the hover thrust the interface
used) (``qsls ingest LOG --mass``, which rebuilds the
tick log from the log alone). The simulator's own tick log stays beside the ULog
(``ticks.parquet``), so what the log gives can be compared with the truth.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from qsls.pipeline.calibrate.options import CalibrateOptions, RecordedFlights
from qsls.pipeline.core.config import merge
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.core.workers import run_flights
from qsls.pipeline.ingest.options import IngestOptions
from qsls.pipeline.ingest.stage import ingest
from qsls.pipeline.sim.options import SimOptions
from qsls.pipeline.sim.simulate import simulate


@dataclass(frozen=True)
class StandinJob:
    """One stand-in flight: where it is written and what it flies."""

    name: str
    role: str
    sim: dict[str, Any]
    log_dir: str
    ingest_dir: str
    ingest: dict[str, Any]


def standin_sim(
    options: CalibrateOptions, folder: Path, seed: int, offset: tuple[float, float, float]
) -> dict[str, Any]:
    """The flight's simulate options: the run's vehicle, reference and estimator, the
    candidate's exported C behind the PX4 interface, logged as a ULog."""
    sim = options.sim.model_dump(mode="json")
    ref = dict(sim.get("reference") or {})
    over: dict[str, Any] = {
        "seed": seed,
        "duration": options.duration,
        "controller": {"kind": str(folder.resolve()), "backend": "c"},
        "vio": {"perception": options.conditions[0]},
        "px4": {"interface": "px4"},
        "log": {"format": options.standin_log},
    }
    if any(offset):
        cx, cy = ref.get("center", (0.0, 0.0))
        over["reference"] = {
            "center": [float(cx) + offset[0], float(cy) + offset[1]],
            "height": float(ref.get("height", 1.0)) + offset[2],
        }
    return SimOptions.model_validate(merge(sim, over)).model_dump(mode="json")


def fly_standin(job: StandinJob) -> str:
    """Fly one stand-in flight and ingest its ULog (in a worker: paths in, path out)."""
    opts = SimOptions.model_validate(job.sim)
    log = simulate(opts, Path(job.log_dir), force=True).bag
    ingest([log], IngestOptions.model_validate(job.ingest), Path(job.ingest_dir), force=True)
    return job.ingest_dir


def standin_flights(
    folders: Sequence[Path],
    options: CalibrateOptions,
    root: Path,
    dt: float,
    offsets: Callable[[int], tuple[float, float, float]],
    progress: Progress = NULL_PROGRESS,
) -> RecordedFlights:
    """Fly every candidate's stand-in flights into ``root`` (``logs/<name>/`` with the log and
    ``flights/<name>/``, the ingest folder) on the pool; the ingest folders by role."""
    calib, valid = options.seed_lists()
    roles = (("calibration", calib), ("range", options.range_seeds), ("validation", valid))
    ingest: dict[str, Any] = {
        "dt": dt,
        "align": "none",
        "time_offset": 0.0,
        "mass": float(options.sim.vehicle.mass),
    }
    if options.standin_log == "mavros":  # a bag states no hover thrust: the user gives it
        ingest["hover_thrust"] = float(options.sim.px4.estimate)
    jobs = [
        StandinJob(
            name := f"{role}_{f.name}_s{s}",
            role,
            standin_sim(options, f, s, offsets(s) if role == "range" else (0.0, 0.0, 0.0)),
            str(root / "logs" / name),
            str(root / "flights" / name),
            ingest,
        )
        for role, seeds in roles
        for f in folders
        for s in seeds
    ]
    run_flights(fly_standin, jobs, options, progress, "stand-in flights", "stand-in")
    by = {r: [Path(j.ingest_dir) for j in jobs if j.role == r] for r, _ in roles}
    return RecordedFlights(
        calibration=by["calibration"], range=by["range"], validation=by["validation"]
    )
