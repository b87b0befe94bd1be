"""Tune the PD for tracking at 10 Hz in regular perception (pipeline/fly/pdtune.py).

    python benchmarks/tune_pd.py                 # the camera loop, tuning seeds 100 and 101
    python benchmarks/tune_pd.py --vio emulator  # the VIO emulator instead
    python benchmarks/tune_pd.py --smoke         # 2 x 1 gains, one seed, 9 s (smokemode.py)

The paper's circle (radius 1 m, period 5 s, height 1 m, three laps, 23 s), the horizontal
gains over a grid, the height's kept (kp_z 4, kd_z 3). Prints every pair's score (the mean
circle tracking RMS with 1 s smoothing over the tuning seeds) and the tuned gains. The
tuning seeds (100, 101) are design flights: the fly stage judges the tuned PD on others.
"""

from __future__ import annotations

import sys

from smokemode import requested, require

from qsls.pipeline.fly.pdtune import tune_pd

KP = (2.0, 5.0, 8.0, 11.0, 14.0, 17.0)
KD = (2.2, 4.0, 5.5, 7.0)


def main() -> None:
    vio = sys.argv[sys.argv.index("--vio") + 1] if "--vio" in sys.argv else "camera"
    flight = {
        "duration": 23.0,
        "reference": {"kind": "circle", "radius": 1.0, "period": 5.0, "height": 1.0, "laps": 3},
        "vio": {"kind": vio},
    }
    kp_grid, kd_grid, seeds = KP, KD, (100, 101)
    if requested():  # one lap after the hold, take-off and approach (7 s)
        flight = {**flight, "duration": 9.0}
        flight["reference"] = {**flight["reference"], "laps": 1}
        kp_grid, kd_grid, seeds = (2.0, 5.0), (4.0,), (100,)
    res = tune_pd(flight, kp_grid, kd_grid, seeds=seeds, workers=2)
    for kp, kd, s in res.grid:
        print(f"kp {kp:5.1f}  kd {kd:4.1f}  circle tracking RMS {s:.4f} m")
    print(
        f"tuned ({res.estimator}, {res.rate_hz:g} Hz): kp {res.kp} kd {res.kd} "
        f"score {res.score_m:.4f} m"
    )
    require(
        0 < res.score_m < float("inf") and res.score_m == min(s for _, _, s in res.grid),
        "a finite tuned score, the grid's least",
    )


if __name__ == "__main__":
    main()
