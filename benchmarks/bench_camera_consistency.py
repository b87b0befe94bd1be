"""Consistency of the camera loop's MSCKF and how often it re-initializes.

    python benchmarks/bench_camera_consistency.py            # NEES replays + 10 degraded flights
    python benchmarks/bench_camera_consistency.py --quick    # 3 seeds each
    python benchmarks/bench_camera_consistency.py --smoke    # 3 s replays, one 4 s flight

NEES: the 20 s figure eight of tests/test_camera.py replayed (IMU and image noise) in the
regular light (1.0, texture 1.0) and the degraded one (0.35, texture 0.45): the mean NEES of
``[p, v]`` (6 dof: a consistent filter has 6) and the fraction of frames inside its two-sided
chi-square 99% band, per seed. Resets: the held-out flights of configs/paper_sim_camera.yaml
(SE3, circle of 1 m in 5 s, three laps) in the degraded condition, seeds 0-9: resets, their
times, the largest estimation error, crashes. Re-initialization: the closed-form solution
(pipeline/sim/camera/vinit.py) of the estimator's window (1 s of IMU samples and tracks)
taken once per second (from 2 s on) of the figure-eight replays, against the truth: the
velocity and the gravity direction in the current body frame (what it initializes; position
and yaw it keeps), the share of windows it accepts, and the share of accepted ones whose
velocity error is within 3 of its reported standard deviations. ``--smoke``
(``smokemode.py``): one seed each, replays of 3 s, one reset flight of 4 s.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.stats import chi2
from smokemode import requested, require

from qsls.pipeline.core.rotations import quat_to_matrix
from qsls.pipeline.sim.camera.loop import CameraVio, replay, trajectory_states
from qsls.pipeline.sim.camera.options import CameraOptions
from qsls.pipeline.sim.camera.vinit import InitSolution
from qsls.pipeline.sim.closedloop import FlightOptions, fly

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests.reference_impl
from tests.reference_impl import thrust_attitudes


def figure_eight(seconds: float, hz: float = 200.0):
    """The figure eight of tests/test_camera.py (1 m half-width, 10 s period)."""
    t = np.arange(round(seconds * hz) + 1) / hz
    w = 2 * np.pi / 10.0
    p = np.stack([np.sin(w * t), 0.5 * np.sin(2 * w * t), 1.0 + 0.1 * np.sin(w * t)], 1)
    acc = np.stack(
        [-w * w * np.sin(w * t), -2 * w * w * np.sin(2 * w * t), -0.1 * w * w * np.sin(w * t)], 1
    )
    return t, p, thrust_attitudes(acc)


def nees_rows(seeds: list[int], seconds: float = 20.0) -> None:
    lo, hi = chi2.ppf([0.005, 0.995], 6)
    t, p, q = figure_eight(seconds)
    print(f"{'condition':10s} {'seed':>4s} {'mean NEES':>10s} {'in band':>8s} {'resets':>7s}")
    for name, light, texture in (("regular", 1.0, 1.0), ("degraded", 0.35, 0.45)):
        means, bands = [], []
        for seed in seeds:
            _, _, loop = replay(CameraOptions(), light, texture, seed, t, p, q, record=True)
            nees = np.array(loop.nees)[1:, 1]
            inside = float(np.mean((nees > lo) & (nees < hi)))
            means.append(float(nees.mean()))
            bands.append(inside)
            require(bool(np.isfinite(nees).all()), f"{name} seed {seed}: a finite NEES")
            print(f"{name:10s} {seed:4d} {nees.mean():10.2f} {inside:8.2f} {len(loop.resets):7d}")
        print(f"{name:10s} {'all':>4s} {np.mean(means):10.2f} {np.mean(bands):8.2f}")


def reset_rows(seeds: list[int], seconds: float | None = None) -> None:
    print(f"\n{'seed':>4s} {'resets':>7s} {'times (s)':24s} {'max err (m)':>11s} {'crashed':>8s}")
    counts = []
    for seed in seeds:
        log = fly(
            FlightOptions.model_validate(
                {
                    "seed": seed,
                    "duration": seconds,
                    "reference": {"kind": "circle", "radius": 1.0, "period": 5.0,
                                  "height": 1.0, "laps": 3},
                    "controller": {"kind": "se3"},
                    "vio": {"kind": "camera", "perception": "degraded"},
                }
            )
        )  # fmt: skip
        d = log.emulator
        counts.append(d["resets"])
        err = float(np.linalg.norm(log.vio_e[:, :3], axis=1).max())
        times = ", ".join(f"{x:.2f}" for x in d["reset_times_s"])
        print(f"{seed:4d} {d['resets']:7d} {times:24s} {err:11.3f} {log.crashed!s:>8s}")
    print(f"{'all':>4s} {sum(counts):7d} (flights with a reset: {sum(c > 0 for c in counts)})")


def init_rows(seeds: list[int], seconds: float = 20.0) -> None:
    t, p, q = figure_eight(seconds)
    s, h_ns = trajectory_states(t, p, q)
    rs = quat_to_matrix(s[:, 6:10])
    g = np.array([0.0, 0.0, -9.81])
    print(
        f"\n{'condition':10s} {'windows':>7s} {'accepted':>8s} {'dv median':>9s} {'dv p90':>7s} "
        f"{'dv max':>7s} {'tilt median':>11s} {'tilt p90':>8s} {'tilt max':>8s} {'<3 sigma':>8s}"
    )
    for name, light, texture in (("regular", 1.0, 1.0), ("degraded", 0.35, 0.45)):
        dv, tilt, within, tried = [], [], [], 0
        for seed in seeds:
            loop = CameraVio(CameraOptions(), light, texture, seed, 9.81, h_ns)
            loop.start(s[0])
            for i in range(len(t) - 1):
                loop.step(s[i], s[i + 1])
                if (i + 1) % 200 or t[i + 1] < 2.0:
                    continue
                assert loop.estimator is not None
                sol = loop.estimator.solve_window()
                tried += 1
                if not isinstance(sol, InitSolution):
                    continue
                r = rs[i + 1]
                v_true, g_true = r.T @ s[i + 1, 3:6], r.T @ g
                v_est, g_est = sol.r_0m.T @ sol.v_m, sol.r_0m.T @ sol.g0
                e = v_est - v_true
                dv.append(float(np.linalg.norm(e)))
                cov = sol.r_0m.T @ sol.cov_v @ sol.r_0m
                within.append(float(e @ np.linalg.solve(cov, e)) < chi2.ppf(0.997, 3))
                c = float(g_est @ g_true) / 9.81**2
                tilt.append(float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))))
        a, b = np.array(dv), np.array(tilt)
        require(len(a) > 0, f"{name}: the initialization accepts a window")
        print(
            f"{name:10s} {tried:7d} {len(a):8d} {np.median(a):9.3f} {np.percentile(a, 90):7.3f} "
            f"{a.max():7.3f} {np.median(b):11.3f} {np.percentile(b, 90):8.3f} {b.max():8.3f} "
            f"{np.mean(within):8.2f}"
        )


def main(argv: list[str]) -> None:
    if requested(argv):
        nees_rows([3], 3.0)
        init_rows([3], 3.0)
        reset_rows([0], 4.0)
        return
    quick = "--quick" in argv
    seeds = [0, 1, 2] if quick else list(range(10))
    nees_rows([3, 4, 5] if quick else [3, 4, 5, 6, 7])
    init_rows([3, 4] if quick else [3, 4, 5, 6, 7])
    reset_rows(seeds)


if __name__ == "__main__":
    main(sys.argv[1:])
