"""Benchmark: flights for a calibrated certificate (issue 37).

Run: ``python benchmarks/bench_flights.py [--flights 200] [--duration 20] [--jobs 2]
[--controller DIR] [--smoke]``

A calibrated certificate needs hundreds of flights of the candidate. Cases, the same PD
flights (seeds 0.., regular perception, the default circle) in this run:

0. the closed loop alone (``closedloop.fly``, emulator), the PD and a certified SLS controller
   (``--controller``, default the quickstart's calibrated ``l1_robust`` under
   ``runs/quickstart``, made by ``qsls run configs/quickstart.yaml`` into a temporary folder
   when missing), flown the fast way and the straightforward way (``stepwise=True``: the
   vehicle in whole-array numpy, one emulator call per VIO sample), taken in turns; the two
   logs must be identical to the bit;
1. the fly stage's flight (``fly.flights.run_job``): the closed loop, its bag written, the bag
   ingested, the metrics computed: what ``qsls evaluate --fly`` does per flight;
2. the calibration's flight (``calibrate.flights.fly_job``): the closed loop and its tick
   log, which is all a flight's score reads (no bag, no ingest);
3. ``--flights`` calibration flights on the local pool of ``--jobs`` processes (wall time;
   the target: 200 flights of 20 s in at most 2 minutes on 2 cores);
4. with ``--scheduler ADDRESS``, the same flights on that Dask cluster, their tick logs
   compared with the pool's (identical required).

Reported: CPU seconds per flight and times real time per core for 0, flights per CPU-second
for 1 and 2, the speed-up, and the wall time of 3 (and 4).

``--smoke`` (``smokemode.py``): 2 s flights, one timed one by one, 2 on the pool, and for the
SLS controller a certified T = 20 one in the quickstart's shape made in a temporary folder
(``tests/controllerfixtures.py``: a real solve and certificate, calibrated by a stand-in).
"""

from __future__ import annotations

import argparse
import dataclasses
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from smokemode import add_flag, require


def _timed(fn):  # type: ignore[no-untyped-def]
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w0, time.process_time() - c0


def _sim(duration: float) -> dict[str, Any]:
    from qsls.pipeline.sim.options import SimOptions

    return {**SimOptions().model_dump(mode="json"), "duration": duration}


def fly_stage_flights(n: int, duration: float, root: Path) -> float:
    """CPU seconds per flight of the fly stage's job (closed loop, bag, ingest, metrics)."""
    from qsls.pipeline.fly.flights import FlyJob, run_job
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


QUICKSTART_L1 = Path("runs/quickstart/calibrate/regular/l1_robust")


def certified_controller(given: str | None, root: Path, smoke: bool = False) -> Path:
    """The SLS controller to fly: ``given``, the quickstart's, or a fresh quickstart's (in
    smoke mode a small certified one, ``tests/controllerfixtures.gated``)."""
    if given:
        return Path(given)
    if smoke:
        sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
        from tests.controllerfixtures import gated

        return gated(root / "l1_robust").folder
    if QUICKSTART_L1.is_dir():
        return QUICKSTART_L1
    out = root / "quickstart"
    subprocess.run(
        [str(Path(sys.executable).parent / "qsls"), "run", "configs/quickstart.yaml", "--out", str(out)],
        check=True, capture_output=True,
    )  # fmt: skip
    return out / "calibrate" / "regular" / "l1_robust"


def _same(a: Any, b: Any) -> bool:
    """Two flight logs equal to the bit."""
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            if x.shape != y.shape or x.tobytes() != y.tobytes():
                return False
        elif f.name != "camera_frame" and x != y:
            return False
    return True


def closed_loop(controller: str, n: int, duration: float) -> tuple[float, float, bool]:
    """CPU seconds per flight, fast and stepwise (taken in turns), and whether all logs agree."""
    from qsls.pipeline.sim.closedloop import FlightOptions, fly

    fast = slow = 0.0
    same = True
    fly(FlightOptions.model_validate({"duration": 1.0, "controller": {"kind": controller}}))
    for s in range(n):
        opts = FlightOptions.model_validate(
            {"duration": duration, "controller": {"kind": controller}, "seed": s}
        )
        a, _, c_fast = _timed(lambda o=opts: fly(o))
        b, _, c_slow = _timed(lambda o=opts: fly(o, stepwise=True))
        fast, slow, same = fast + c_fast, slow + c_slow, same and _same(a, b)
    return fast / n, slow / n, same


def calibration_jobs(n: int, duration: float, folder: str = "pd") -> list[Any]:
    from qsls.pipeline.calibrate.flights import Job

    return [
        Job(name=f"c{s}", controller="pd" if folder == "pd" else "sls", folder=folder, condition="regular", seed=s,
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
    ap.add_argument("--controller", default=None, help="a certified SLS controller folder")
    add_flag(ap)
    a = ap.parse_args()
    if a.smoke:
        a.flights, a.duration, a.sample = 2, 2.0, 1

    from qsls.pipeline.calibrate.flights import fly_job
    from qsls.pipeline.core.pools import run_tasks

    with tempfile.TemporaryDirectory() as tmp:
        sls = certified_controller(a.controller, Path(tmp), a.smoke)
        print(f"{a.duration:g} s emulator flights, closed loop alone, CPU s per flight "
              f"(mean of {a.sample}; stepwise = whole-array vehicle, one emulator call per sample):")  # fmt: skip
        for name, kind in (("pd", "pd"), (f"SLS {sls}", str(sls))):
            new, old, same = closed_loop(kind, a.sample, a.duration)
            print(f"  {name}: {new:.3f} s = {a.duration / new:.1f}x real time per core; stepwise "
                  f"{old:.3f} s = {a.duration / old:.1f}x; {old / new:.2f}x faster; "
                  f"identical logs: {same}")  # fmt: skip
            require(same, f"{name}: the fast and the stepwise flights' logs are identical")
        stage = fly_stage_flights(a.sample, a.duration, Path(tmp))

        # the batch: the certified controller's own calibration flights, as calibrate flies them
        jobs = calibration_jobs(a.flights, a.duration, str(sls))
        tasks = [(fly_job, j) for j in jobs]
        local, wall, _ = _timed(lambda: run_tasks(tasks, a.jobs))
        print(f"{a.flights} calibration flights of the certified controller on a local pool of "
              f"{a.jobs}: {wall:.1f} s wall (target: 200 flights of 20 s in 120 s on 2 cores)")  # fmt: skip
        if a.scheduler:
            remote, wall_d, _ = _timed(lambda: run_tasks(tasks, a.jobs, scheduler=a.scheduler))
            same = all(
                x.frame().equals(y.frame()) for x, y in zip(local, remote, strict=True)
            )  # fmt: skip
            print(f"  the same on the Dask cluster at {a.scheduler}: {wall_d:.1f} s wall; "
                  f"tick logs identical: {same}")  # fmt: skip
            require(same, "the Dask cluster's tick logs equal the local pool's")
    cal = sum(_timed(lambda j=j: fly_job(j))[2] for j in calibration_jobs(a.sample, a.duration))
    cal /= a.sample
    print(f"{a.duration:g} s flights, CPU seconds per flight (mean of {a.sample}):")
    print(
        f"  fly stage (closed loop + bag + ingest): {stage:.3f} s  ({1 / stage:.2f} flights/CPU-s)"
    )
    print(f"  calibration flight (closed loop + ticks): {cal:.3f} s  ({1 / cal:.2f} flights/CPU-s)")
    print(f"  -> {stage / cal:.2f}x more flights per CPU-second; "
          f"{a.duration / cal:.1f}x real time per core")  # fmt: skip


if __name__ == "__main__":
    main()
