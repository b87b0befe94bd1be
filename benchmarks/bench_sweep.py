"""Benchmark of ``qsls sweep`` at 1000 points (issue 27): ``python benchmarks/bench_sweep.py``.

1. The sweep of ``configs/bench_sweep.yaml`` (S x T x eps_e x radius x cost, 5 x 4 x 5 x 5 x 2)
   on one process, on two (``--jobs 2``) and on a local Dask cluster (a loopback scheduler
   and two single-threaded worker processes): wall seconds and CPU seconds (this process, its
   pool workers, the Dask workers); the three tables must be identical.
2. Its largest feasible S for each of the 100 settings (T x eps_e x radius), two ways: one
   Dinkelbach run and one smallest-||Phi_xy|| solve per setting (before issue 27), and one
   Dinkelbach run per T and radius serving every eps_e (``eps_e`` only shifts ``S_max``) with
   the smallest ||Phi_xy|| solved once per T: solves, CPU seconds, identical answers.
Target: the 1000-point sweep in <= 30 s on 2 cores.

``--smoke`` (``smokemode.py``): the config's settings on a grid of 6 points (:data:`SMOKE_GRID`).
"""

from __future__ import annotations

import argparse
import os
import resource
import time
from pathlib import Path

import pandas as pd
import yaml
from smokemode import add_flag, requested, require

from qsls.pipeline.control import largest_s, sls
from qsls.pipeline.control.sweep import (
    ABOVE_S_MAX,
    NECESSARY,
    SweepOptions,
    compute,
    grid_points,
    s_max_specs,
)
from qsls.pipeline.core.config import validate
from qsls.pipeline.core.plant import quadrotor_model
from qsls.pipeline.premise.numbers import PremiseNumbers

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "bench_sweep.yaml"
SMOKE_GRID = {
    "S": [0.05, 0.5, 0.9],
    "T": [10],
    "eps_e": [0.02, 0.2],
    "radius": [1.0],
    "cost": ["qr"],
}
"""The smoke mode's grid: one point answered by the necessary condition (S 0.9, eps_e 0.2)."""


def _cpu() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def _worker_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def options() -> SweepOptions:
    data = yaml.safe_load(CONFIG.read_text())
    if requested():
        data["grid"] = SMOKE_GRID
    return validate(SweepOptions, data, str(CONFIG))


def run_local(jobs: int) -> tuple[float, float, pd.DataFrame, pd.DataFrame]:
    sls._CACHE.clear()
    largest_s._MIN_XY.clear()
    c0, t0 = _cpu(), time.perf_counter()
    table, smax, _ = compute(options(), jobs=jobs)
    return time.perf_counter() - t0, _cpu() - c0, table, smax


def run_dask(workers: int) -> tuple[float, float, pd.DataFrame, pd.DataFrame]:
    from distributed import Client, LocalCluster

    with LocalCluster(
        n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
        dashboard_address=None,
    ) as cluster, Client(cluster) as client:  # fmt: skip
        client.run(lambda: __import__("qsls.pipeline.control.sweep"))  # imports are not timed
        before = sum(client.run(_worker_cpu).values())
        c0, t0 = _cpu(), time.perf_counter()
        table, smax, _ = compute(options(), scheduler=cluster.scheduler_address)
        wall = time.perf_counter() - t0
        cpu = _cpu() - c0 + sum(client.run(_worker_cpu).values()) - before
    return wall, cpu, table, smax


def _timed(task: tuple) -> tuple[int, float, object]:
    fn, arg = task
    c0 = _worker_cpu()
    res = fn(arg)
    return os.getpid(), _worker_cpu() - c0, res


def cpu_balance(jobs: int = 2) -> tuple[float, float, float]:
    """The sweep's tasks as :func:`compute` runs them (first the largest-S tasks, whose
    answers mark the points above each setting's largest S, then chunks of points) on ``jobs``
    fresh processes per phase, timed by CPU seconds per worker: ``(main, total, busiest)``,
    ``busiest`` summed over the two phases; on ``jobs`` idle cores the sweep takes about
    ``main + busiest`` seconds (a figure the shared machine's load does not distort)."""
    import multiprocessing as mp
    from collections import defaultdict
    from concurrent.futures import ProcessPoolExecutor

    from qsls.pipeline.control.sweep import make_chunks, mark_above_s_max, run_chunk, s_max_task

    def phase(tasks: list) -> tuple[list, float, float]:
        per_worker: dict[int, float] = defaultdict(float)
        results = []
        with ProcessPoolExecutor(jobs, mp_context=mp.get_context("fork")) as pool:
            for pid, cpu, res in pool.map(_timed, tasks):
                per_worker[pid] += cpu
                results.append(res)
        return results, sum(per_worker.values()), max(per_worker.values())

    c0 = time.process_time()
    opts = options()
    points = grid_points(opts, None)
    main = time.process_time() - c0
    sls._CACHE.clear()
    largest_s._MIN_XY.clear()
    found, total1, busy1 = phase([(s_max_task, sp) for sp in s_max_specs(points)])
    c0 = time.process_time()
    mark_above_s_max(points, {r["key"]: r["ratio_upper"] for res in found for r in res})
    chunks = make_chunks(points, jobs * opts.chunks_per_job)
    main += time.process_time() - c0
    _, total2, busy2 = phase([(run_chunk, c) for c in chunks])
    return main, total1 + total2, busy1 + busy2


def _premise(spec: dict, eps_e: float) -> PremiseNumbers:
    """The premise of one sweep setting at ``eps_e`` (``S`` aside)."""
    return PremiseNumbers(
        eps=float(eps_e), S=0.0, radius=spec["radius"], eps_w=spec["eps_w"], delta=spec["delta"]
    )


def s_max_both_ways() -> list[tuple[str, int, int, float, pd.Series]]:
    """``(way, tasks, solves, cpu s, s_max per setting)`` for the sweep's 100 settings."""
    points = grid_points(options(), None)
    specs = s_max_specs(points)
    model = quadrotor_model()
    out = []
    sls._CACHE.clear()
    largest_s._MIN_XY.clear()
    c0 = time.process_time()
    solves, got = 0, {}
    for spec in specs:  # before: every (T, eps_e, radius) its own Dinkelbach and min ||Phi_xy||
        for eps_e in spec["eps_e"]:
            ms = largest_s.max_feasible_s(model, spec["T"], _premise(spec, eps_e))
            largest_s._MIN_XY.clear()
            largest_s.min_phi_xy(model, spec["T"])
            solves += ms.iterations + 1
            got[(spec["T"], eps_e, spec["radius"])] = ms.s_max
    out.append(("per setting", len(got), solves, time.process_time() - c0, pd.Series(got)))
    sls._CACHE.clear()
    largest_s._MIN_XY.clear()
    c0 = time.process_time()
    solves, got = 0, {}
    for spec in specs:
        ratio = largest_s.max_ratio(model, spec["T"], _premise(spec, 0.0))
        solves += ratio.iterations
        n_min = len(largest_s._MIN_XY)
        largest_s.min_phi_xy(model, spec["T"])
        solves += len(largest_s._MIN_XY) - n_min
        for eps_e in spec["eps_e"]:
            ms = largest_s.max_feasible_s(model, spec["T"], _premise(spec, eps_e), ratio=ratio)
            got[(spec["T"], eps_e, spec["radius"])] = ms.s_max
    out.append(("per T and radius", len(specs), solves, time.process_time() - c0, pd.Series(got)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-dask", action="store_true", help="skip the Dask cluster run")
    add_flag(ap)
    args = ap.parse_args()
    import cvxpy  # noqa: F401  (import time is not part of any measurement)

    runs = {"1 process": run_local(1), "2 processes": run_local(2)}
    if not args.no_dask:
        runs["Dask, 2 workers"] = run_dask(2)
    ref = runs["1 process"]
    n = len(ref[2])
    feasible = int(ref[2]["feasible"].sum())
    t = ref[2]
    necessary = int((t["solver_status"] == NECESSARY).sum())
    above = int((t["solver_status"] == ABOVE_S_MAX).sum())
    grid = "the smoke grid" if args.smoke else CONFIG.name
    print(f"\n{n}-point sweep ({grid}): {feasible} feasible; answered without the solver:")
    print(f"{necessary} by the necessary condition S + eps_e/r < 1, {above} by S above the")
    print("setting's largest feasible S (its Dinkelbach run)")
    hdr = f"{'executor':18s} {'wall s':>8s} {'cpu s':>8s} {'table identical':>16s}"
    print(hdr)
    print("-" * len(hdr))
    for name, (wall, cpu, table, smax) in runs.items():
        same = table.drop(columns=["build_time_s", "solve_time_s"]).equals(
            ref[2].drop(columns=["build_time_s", "solve_time_s"])
        ) and smax.equals(ref[3])
        print(f"{name:18s} {wall:8.2f} {cpu:8.2f} {same!s:>16s}")
        require(same, f"{name}: the same table and largest S as one process")
    main, total, busiest = cpu_balance(2)
    print(
        f"CPU balance on 2 processes: {total:.2f} CPU s in the workers, the busiest {busiest:.2f};"
        f" with {main:.2f} s for the grid, about {main + busiest:.1f} s on 2 idle cores"
    )
    print(f"target: <= 30 s on 2 cores (2 processes: {runs['2 processes'][0]:.1f} s wall here)")
    ways = s_max_both_ways()
    print(f"\nlargest feasible S for the sweep's {len(ways[0][4])} settings (T x eps_e x radius)")
    hdr = f"{'way':18s} {'tasks':>6s} {'solves':>7s} {'cpu s':>7s} {'same S_max':>11s}"
    print(hdr)
    print("-" * len(hdr))
    for way, tasks, solves, cpu, got in ways:
        same = bool((got == ways[0][4]).all())
        print(f"{way:18s} {tasks:6d} {solves:7d} {cpu:7.2f} {same!s:>11s}")
        require(same, f"{way}: the same largest S as per setting")
    print(f"load average after the run: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
