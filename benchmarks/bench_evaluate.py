"""Benchmark of qsls evaluate: the bound check's nearest-training-state distances, and flying.

Run: ``python benchmarks/bench_evaluate.py [--fit FITDIR --synth SYNTHDIR | --prepare DIR]
[--quick] [--smoke]``.

1. Distance of every held-out state to the nearest training state: KD-tree (infinity norm,
   what ``evaluate`` uses) against chunked brute force numpy, same answer checked.
2. With ``--fit`` and ``--synth`` (outputs of ``qsls fit`` / ``qsls synth``): the default fly
   evaluation (four controllers + SE3, two conditions, three seeds, 30 s flights) on a process
   pool of 2 against the same flights one after another (``--quick``: one seed, 10 s).

``--smoke`` (``smokemode.py``): 2 000 training and 300 held-out states, then both parts on
two 8 s training flights prepared in a temporary folder, one seed, 3 s flights, regular
perception.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
from smokemode import add_flag, require, scratch


def brute_nearest(train: np.ndarray, query: np.ndarray, chunk: int = 256) -> np.ndarray:
    out = np.empty(len(query))
    for a in range(0, len(query), chunk):
        q = query[a : a + chunk]
        out[a : a + chunk] = np.abs(q[:, None, :] - train[None]).max(axis=2).min(axis=1)
    return out


def bench_distance(smoke: bool = False) -> list[tuple[str, float, str]]:
    from qsls.pipeline.evaluate.training import TrainingData

    rng = np.random.default_rng(0)
    rows = []
    sizes = ((2_000, 300),) if smoke else ((20_000, 3_000), (100_000, 10_000))
    for n_train, n_query in sizes:
        t = np.linspace(0, 200, n_train)
        train = np.c_[np.cos(t), np.sin(t), 1 + 0.05 * np.sin(7 * t), -np.sin(t), np.cos(t), 0 * t]
        train += rng.normal(scale=0.02, size=train.shape)
        query = train[rng.integers(0, n_train, n_query)] + rng.normal(scale=0.1, size=(n_query, 6))
        t0 = time.perf_counter()
        d, _ = TrainingData.build(train, np.ones(6)).nearest(query)
        t_tree = time.perf_counter() - t0
        if n_train <= 20_000:
            t0 = time.perf_counter()
            ref = brute_nearest(train, query)
            t_brute = time.perf_counter() - t0
            require(np.allclose(d, ref), "the KD-tree's distances equal brute force's")
            rows.append((f"nearest {n_train} x {n_query}: brute numpy", t_brute, ""))
        rows.append(
            (
                f"nearest {n_train} x {n_query}: KD-tree",
                t_tree,
                f"{t_brute / t_tree:.0f}x faster" if n_train <= 20_000 else "",
            )
        )
    return rows


def bench_fly(
    fit: Path, synth: Path, quick: bool, smoke: bool = False
) -> list[tuple[str, float, str]]:
    from qsls.pipeline.fly.options import FlyOptions
    from qsls.pipeline.fly.stage import fly_evaluate

    kw: dict = {"seeds": [0], "duration": 10.0} if quick else {}
    if smoke:
        kw = {"seeds": [0], "duration": 3.0, "conditions": ["regular"]}
    rows = []
    tmp = Path(tempfile.mkdtemp(prefix="bench-eval-"))
    try:
        times, tables = {}, {}
        for jobs in (2, 1):
            t0 = time.perf_counter()
            res = fly_evaluate(
                fit, [synth], FlyOptions(jobs=jobs, figures=True, **kw), tmp / f"j{jobs}"
            )
            times[jobs] = time.perf_counter() - t0
            rows.append(
                (f"fly evaluation, {len(res.flights)} flights, jobs={jobs}", times[jobs], "")
            )
            tables[jobs] = res.flights
        rows[0] = (rows[0][0], rows[0][1], f"{times[1] / times[2]:.2f}x vs sequential")
        same = tables[2].equals(tables[1])
        rows[1] = (rows[1][0], rows[1][1], f"the same flights table: {same}")
        require(same, "the pool's flights table equals the sequential one's")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return rows


def prepare(root: Path, duration: float = 30.0) -> tuple[Path, Path]:
    """Training flights (SE3, regular, 2 x ``duration`` s) -> ingest -> fit -> synth (paper's
    four)."""
    from qsls.pipeline.control.synth import SynthOptions, synth
    from qsls.pipeline.errormodel.fit import FitOptions, fit
    from qsls.pipeline.ingest.stage import IngestOptions, ingest
    from qsls.pipeline.sim.simulate import SimOptions, simulate

    flights = []
    for seed in (100, 101):
        res = simulate(SimOptions(seed=seed, duration=duration), root / f"sim{seed}", force=True)
        ingest([res.bag], IngestOptions(), root / f"train{seed}", force=True)
        flights.append(root / f"train{seed}")
    fit(flights, FitOptions(radius=1.0), root / "fit", force=True)
    synth(root / "fit", SynthOptions(T=20, S="p50", eps_e="p99"), root / "synth", force=True)
    return root / "fit", root / "synth"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fit", type=Path)
    ap.add_argument("--synth", type=Path)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--prepare", type=Path, help="build --fit/--synth here first (simulate..synth)")
    ap.add_argument("--skip-distance", action="store_true")
    add_flag(ap)
    a = ap.parse_args()
    if a.smoke and not (a.fit and a.synth):
        a.fit, a.synth = prepare(a.prepare or scratch(), 8.0)
    elif a.prepare:
        a.fit, a.synth = prepare(a.prepare)
    rows = [] if a.skip_distance else bench_distance(a.smoke)
    if a.fit and a.synth:
        rows += bench_fly(a.fit, a.synth, a.quick, a.smoke)
    w = max(len(r[0]) for r in rows)
    print(f"{'case':<{w}}  {'seconds':>9}  note")
    for name, sec, note in rows:
        print(f"{name:<{w}}  {sec:9.3f}  {note}")


if __name__ == "__main__":
    main()
