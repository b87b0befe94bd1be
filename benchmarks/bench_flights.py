"""Benchmark: flights for a calibrated certificate (issue 37).

Run: ``python benchmarks/bench_flights.py [--flights 200] [--duration 20] [--jobs 2]``

A calibrated certificate needs hundreds of flights of the candidate. Cases, the same PD
flights (seeds 0.., regular perception, the default circle) in this run:

1. the fly stage's flight (``evaluate.fly.run_job``): the closed loop, its bag written, the bag
   ingested, the metrics computed: what ``qsls evaluate --fly`` does per flight;
2. the calibration's flight (``evaluate.calibrate.fly_job``): the closed loop and its tick
   log, which is all a flight's score reads (no bag, no ingest);
3. ``--flights`` calibration flights on the local pool of ``--jobs`` processes (wall time;
   the target: 200 flights of 20 s in at most 2 minutes on 2 cores);
4. with ``--scheduler ADDRESS``, the same flights on that Dask cluster, their tick logs
   compared with the pool's (identical required).

Reported: CPU seconds per flight and flights per CPU-second for 1 and 2, the speed-up, and the
wall time of 3 (and 4).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path
from typing import Any


def _timed(fn):  # type: ignore[no-untyped-def]
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w0, time.process_time() - c0


def _sim(duration: float) -> dict[str, Any]:
    from qsls.pipeline.sim.options import SimOptions

    return {**SimOptions().model_dump(mode="json"), "duration": duration}


def fly_stage_flights(n: int, duration: float, root: Path) -> float:
    """CPU seconds per flight of the fly stage's job (closed loop, bag, ingest, metrics)."""
    from qsls.pipeline.evaluate.fly import FlyJob, run_job
    from qsls.pipeline.ingest.options import IngestOptions

    ingest = IngestOptions(dt=0.1).model_dump(mode="json")
    cpu = 0.0
    for s in range(n):
        job = FlyJob(
            name=f"f{s}", controller="pd", spec="pd", condition="regular", seed=s,
            sim=_sim(duration), ingest=ingest, sim_dir=str(root / f"sim{s}"),
            flight_dir=str(root / f"flight{s}"),
        )  # fmt: skip
        cpu += _timed(lambda j=job: run_job(j))[2]
    return cpu / n


def calibration_jobs(n: int, duration: float) -> list[Any]:
    from qsls.pipeline.evaluate.calibrate import Job

    return [
        Job(name=f"c{s}", controller="pd", folder="pd", condition="regular", seed=s,
            role="calibration", sim=_sim(duration), offset=(0.0, 0.0, 0.0))
        for s in range(n)
    ]  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--flights", type=int, default=200)
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--sample", type=int, default=5, help="flights timed one by one in 1 and 2")
    ap.add_argument("--scheduler", default=None)
    a = ap.parse_args()

    from qsls.pipeline.core.pools import run_tasks
    from qsls.pipeline.evaluate.calibrate import fly_job

    with tempfile.TemporaryDirectory() as tmp:
        stage = fly_stage_flights(a.sample, a.duration, Path(tmp))
    cal = sum(_timed(lambda j=j: fly_job(j))[2] for j in calibration_jobs(a.sample, a.duration))
    cal /= a.sample
    print(f"{a.duration:g} s flights, CPU seconds per flight (mean of {a.sample}):")
    print(f"  fly stage (closed loop + bag + ingest): {stage:.3f} s  ({1 / stage:.2f} flights/CPU-s)")
    print(f"  calibration flight (closed loop + ticks): {cal:.3f} s  ({1 / cal:.2f} flights/CPU-s)")
    print(f"  -> {stage / cal:.2f}x more flights per CPU-second; "
          f"{a.duration / cal:.1f}x real time per core")  # fmt: skip

    jobs = calibration_jobs(a.flights, a.duration)
    tasks = [(fly_job, j) for j in jobs]
    local, wall, _ = _timed(lambda: run_tasks(tasks, a.jobs))
    print(f"{a.flights} calibration flights on a local pool of {a.jobs}: {wall:.1f} s wall "
          f"(target: 200 flights of 20 s in 120 s on 2 cores)")  # fmt: skip
    if a.scheduler:
        remote, wall_d, _ = _timed(lambda: run_tasks(tasks, a.jobs, scheduler=a.scheduler))
        same = all(
            x.frame().equals(y.frame()) for x, y in zip(local, remote, strict=True)
        )  # fmt: skip
        print(f"  the same on the Dask cluster at {a.scheduler}: {wall_d:.1f} s wall; "
              f"tick logs identical: {same}")  # fmt: skip


if __name__ == "__main__":
    main()
