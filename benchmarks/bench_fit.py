"""Benchmark of the S-slope pair engine (``qsls fit``) against the naive way.

    python benchmarks/bench_fit.py            # all cases
    python benchmarks/bench_fit.py --quick    # smaller sizes
    python benchmarks/bench_fit.py --smoke    # 500 and 2 000 samples (smokemode.py)

Cases (each in its own process, so the peak memory is its own):
- ``engine 20k``: :func:`qsls.pipeline.errormodel.slopes.pair_slopes` on 20k samples of repeated circle laps;
- ``brute 20k``: the chunked brute-force numpy computation (all pairs i < j, 256 rows at a time,
  slopes kept for exact percentiles) on the same samples; the table checks both agree
  (pair count, exact max, percentiles);
- ``engine 100k``: 100k samples (1000 laps) with more than 10^8 pairs inside the radius
  (``engine_x2``: the same with two threads);
- ``fit 100k``: the whole ``fit`` stage on the same samples as 10 flight folders (error model,
  training states; no figures).

Time is wall time (and the process's CPU time, which a busy machine does not inflate), memory
the process's peak resident set (``ru_maxrss``).
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from smokemode import requested, require

RADIUS = 0.12


def samples(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Circle laps (radius 1 m, period 10 s, dt 0.1 s) with tracking deviations; VIO errors."""
    from qsls.pipeline.sim.vio import VioEmulator, VioParams

    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.1
    w = 2 * np.pi / 10.0
    z = np.zeros(n)
    x = np.c_[np.cos(w * t), np.sin(w * t), 1 + z, -w * np.sin(w * t), w * np.cos(w * t), z]
    x += rng.normal(0, 0.05, x.shape)
    e = VioEmulator(VioParams(drift=False), seed).errors(x)
    return x, e


def case(name: str, n: int) -> dict:
    x, e = samples(n)
    t0 = time.perf_counter()
    c0 = os.times()
    out: dict = {"case": name, "n": n}
    if name.startswith("engine"):
        from qsls.pipeline.errormodel.slopes import pair_slopes

        r = pair_slopes(x, e, RADIUS, jobs=2 if name.endswith("x2") else 1)
        out |= {
            "pairs": r.n_pairs,
            "candidates": r.n_candidates,
            "max": r.max,
            "percentiles": r.percentiles,
            "rel_error": r.percentile_rel_error,
        }
    elif name == "brute":
        sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests.reference_impl
        from tests.reference_impl import brute_force_slopes

        allv, mx, cnt = brute_force_slopes(x, e, RADIUS, chunk=256)
        pct = np.percentile(allv, [50, 90, 95, 99])
        out |= {
            "pairs": cnt,
            "candidates": n * (n - 1) // 2,
            "max": mx,
            "percentiles": {f"p{q}": float(v) for q, v in zip((50, 90, 95, 99), pct, strict=True)},
            "rel_error": 0.0,
        }
    elif name == "fit":
        from qsls.pipeline.core.artifacts import StageWriter
        from qsls.pipeline.errormodel.fit import FitOptions, fit
        from qsls.pipeline.ingest.flight import make_flight_frame

        with tempfile.TemporaryDirectory() as tmp:
            folders = []
            for k, (xs, es) in enumerate(
                zip(np.array_split(x, 10), np.array_split(e, 10), strict=True)
            ):
                f = Path(tmp) / f"flight{k}"
                stamps = np.arange(len(xs), dtype=np.int64) * 100_000_000
                with StageWriter(f, "ingest") as w:
                    w.write_parquet("flight.parquet", make_flight_frame(stamps, xs, xs + es))
                folders.append(f)
            t0 = time.perf_counter()
            c0 = os.times()
            res = fit(
                folders,
                FitOptions(radius=RADIUS, min_separation=0.0, figures=False),
                Path(tmp) / "fit",
            )
            m = res.model
            out |= {
                "pairs": m.n_pairs,
                "candidates": res.n_candidates,
                "max": m.s_slope.max,
                "percentiles": m.s_slope.percentiles,
                "rel_error": m.s_slope.percentile_rel_error,
            }
    out["seconds"] = time.perf_counter() - t0
    c1 = os.times()
    out["cpu_s"] = (c1.user - c0.user) + (c1.system - c0.system)
    out["peak_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return out


def run(name: str, n: int) -> dict:
    cmd = [sys.executable, __file__, "--case", name, str(n)]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    if len(sys.argv) >= 4 and sys.argv[1] == "--case":
        print(json.dumps(case(sys.argv[2], int(sys.argv[3]))))
        return
    quick = "--quick" in sys.argv
    small, big = (5_000, 20_000) if quick else (20_000, 100_000)
    if requested():
        small, big = 500, 2_000
    rows = [
        run("engine", small),
        run("brute", small),
        run("engine", big),
        run("engine_x2", big),
        run("fit", big),
    ]
    print(f"radius {RADIUS}, infinity norm, no minimum separation; circle laps with VIO errors")
    hdr = f"{'case':<10}{'samples':>9}{'pairs':>13}{'candidates':>15}{'time s':>9}{'cpu s':>8}{'peak MB':>9}  max / p50 / p99"
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        p = r["percentiles"]
        print(
            f"{r['case']:<10}{r['n']:>9,}{r['pairs']:>13,}{r['candidates']:>15,}"
            f"{r['seconds']:>9.2f}{r['cpu_s']:>8.2f}{r['peak_mb']:>9.0f}  {r['max']:.6g} / {p['p50']:.6g} / {p['p99']:.6g}"
        )
    eng, bru = rows[0], rows[1]
    same_pairs = eng["pairs"] == bru["pairs"]
    same_max = eng["max"] == bru["max"]
    rel = max(
        abs(eng["percentiles"][k] - bru["percentiles"][k]) / bru["percentiles"][k]
        for k in bru["percentiles"]
    )
    print(
        f"\n{small:,} samples: engine vs brute force: pairs equal {same_pairs}, max equal "
        f"{same_max}, largest percentile difference {rel:.2e} (stated bound {eng['rel_error']:.3g}); "
        f"speed-up {bru['seconds'] / eng['seconds']:.1f}x"
    )
    require(same_pairs and same_max, "the engine's pair count and maximum equal brute force's")
    require(rel <= eng["rel_error"], "the engine's percentiles within its stated bound")
    require(
        rows[2]["pairs"] == rows[3]["pairs"] and rows[2]["max"] == rows[3]["max"],
        "one thread and two find the same pairs and maximum",
    )
    print(
        f"{big:,} samples: {rows[2]['pairs']:,} pairs in {rows[2]['seconds']:.1f} s, "
        f"peak {rows[2]['peak_mb']:.0f} MB (target: > 1e8 pairs in <= 20 s and <= 2 GB)"
    )


if __name__ == "__main__":
    main()
