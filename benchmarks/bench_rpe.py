"""RPE against speed: real VIO (EuRoC) beside the VIO emulator with and without its motion parts.

    python benchmarks/bench_rpe.py            # 5 seeds per emulated row
    python benchmarks/bench_rpe.py --quick    # 2 seeds
    python benchmarks/bench_rpe.py FLIGHT...  # the statistic on ingested flight folders only
    python benchmarks/bench_rpe.py --scan     # the calibration of the bias field's position steps
    python benchmarks/bench_rpe.py --smoke    # 1 seed, one lap per figure eight (smokemode.py)

The statistic (:mod:`qsls.pipeline.evaluate.rpe`): the 1 s relative position error over
non-overlapping 1 s windows of an aligned flight, the ratio of its mean over the fastest third
of windows to that over the slowest third, and the Spearman rank correlation rho of window
speed and RPE. Rows:

- ``real``: the three real pairs of ``../shared/data/real`` (README there), ingested with
  :func:`qsls.pipeline.ingest.stage.ingest` (text files, SE(3) alignment, dt 0.1 s);
- ``V1_02 truth``, ``MH_04 truth``: the emulator run on the real ground truth of the two
  distinct flights (EuRoC speeds
  and body rates: positions and attitudes resampled to the emulator's 100 Hz, velocity and
  acceleration by ingest's smoothing differentiator, body rate from consecutive attitudes),
  sampled at 0.1 s like the ingested flights; ``off`` is the emulator before its motion parts
  (blur, drift with motion, feature loss switched off: the naive, position-only model),
  ``on`` the defaults with them;
- ``sim figure8``: closed-loop flights of the PD controller over a figure eight (half-width
  1.5 m, 10 s per lap: 0.6 to 1.3 m/s, after a hold and a climb) on the emulator's estimate (``bias off``: without
  the spatial bias field, to show how much of the speed dependence it makes).

Emulated rows give the mean over seeds and the range [min, max].

``--scan`` shows how the default bias field was chosen (``pipeline/sim/vio.py``,
``RIDGE_POSITION_SCALE``): the ridges' position steps at ``scale`` times their first design
(``FIRST_RIDGES``: 0.04 m, 0.04 m, 0.015 m) on a regular grid, the velocity steps at the
default ``RIDGE_VELOCITY_SCALE`` times theirs (the Lipschitz constant is 0.209 at every
scale), motion parts on, 3 seeds, for each emulated flight of the default run's table. The
rule, fixed before the scan: of the scales at which every seed of every flight falls in the
real range, the middle one (the smaller of two), so that neither edge of the range is grazed.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from smokemode import requested, require

REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
PAIRS = {  # folder: (truth file, the measurement: ratio, rho)
    "euroc_v102_rpg": ("groundtruth_tum.txt", 2.05, 0.70),
    "euroc_mh04_rpg": ("groundtruth_tum.txt", 1.39, 0.26),
    "euroc_v102": ("groundtruth.csv", 1.27, 0.44),
}
TRUTHS = {"V1_02": "euroc_v102", "MH_04": "euroc_mh04_rpg"}  # one per distinct flight
SIM_ROWS = [  # (perception, motion parts, bias field)
    ("regular", False, True),
    ("regular", True, True),
    ("degraded", False, True),
    ("degraded", True, True),
    ("regular", True, False),
]
MOTION = ("blur", "motion_drift", "feature_loss")
RATE_HZ = 100.0
DT = 0.1


def flight_row(folder: Path) -> dict[str, Any]:
    """The statistic on an ingested flight (a folder holding ``flight.parquet``)."""
    from qsls.pipeline.evaluate.rpe import rpe_windows, speed_statistic
    from qsls.pipeline.ingest.flight import Flight

    f = Flight.load(folder)
    return vars(
        speed_statistic(*rpe_windows(f.frame["t"].to_numpy(), f.states(), f.measurements())[1:])
    )


def real_row(name: str, work: Path) -> dict[str, Any]:
    from qsls.pipeline.ingest.stage import IngestOptions, ingest

    truth = REAL / name / PAIRS[name][0]
    o = IngestOptions(vio=REAL / name / "estimate_tum.txt", truth=truth, align="se3", dt=DT)
    ingest([], o, work / name, force=True)
    return flight_row(work / name)


def truth_states(name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(t_ns, x (n, 6), body rate (n, 3), acceleration (n, 3)) of a pair's ground truth at
    ``RATE_HZ``."""
    from scipy.spatial.transform import Rotation, Slerp

    from qsls.pipeline.ingest.align import differentiate
    from qsls.pipeline.ingest.sources.text.reader import read_euroc, read_tum

    path = REAL / name / PAIRS[name][0]
    tr = (read_euroc if path.suffix == ".csv" else read_tum)(path)
    order = np.argsort(tr.header_ns, kind="stable")
    t0, pos, quat = tr.header_ns[order], tr.position[order], tr.orientation[order]
    keep = np.r_[True, np.diff(t0) > 0]
    t0, pos, quat = t0[keep], pos[keep], quat[keep]
    step = round(1e9 / RATE_HZ)
    t = np.arange(t0[0], t0[-1], step, dtype=np.int64)
    p = np.column_stack([np.interp(t, t0, pos[:, k]) for k in range(3)])
    rot = Slerp(t0 * 1e-9, Rotation.from_quat(quat))(t * 1e-9)
    rel = (rot[:-1].inv() * rot[1:]).as_rotvec() * RATE_HZ  # body rate over each step
    omega = np.vstack([rel, rel[-1:]])
    v = differentiate(t, p, 0.1)
    a = differentiate(t, v, 0.1)
    return t, np.hstack([p, v]), omega, a


def emulated_row(
    truth: tuple[np.ndarray, ...], motion: bool, seed: int, vio: dict[str, Any] | None = None
) -> dict[str, Any]:
    from qsls.pipeline.evaluate.rpe import rpe_windows, speed_statistic
    from qsls.pipeline.sim.vio import VioEmulator, VioParams

    t, x, omega, a = truth
    prm = VioParams.model_validate(
        {"rate_hz": RATE_HZ, **dict.fromkeys(MOTION, motion), **(vio or {})}
    )
    e = VioEmulator(prm, seed).errors(x, omega, a)
    k = slice(None, None, round(RATE_HZ * DT))
    return vars(speed_statistic(*rpe_windows(t[k] * 1e-9, x[k], x[k] + e[k])[1:]))


def sim_row(
    motion: bool,
    seed: int,
    perception: str,
    bias: bool,
    vio: dict[str, Any] | None = None,
    laps: int = 6,
) -> dict[str, Any]:
    from qsls.pipeline.evaluate.rpe import rpe_windows, speed_statistic
    from qsls.pipeline.sim.closedloop import FlightOptions, fly

    o = FlightOptions.model_validate(
        {
            "controller": {"kind": "pd"},
            "reference": {"kind": "figure8", "radius": 1.5, "period": 10.0, "laps": laps},
            "vio": {
                "perception": perception,
                "bias": bias,
                **dict.fromkeys(MOTION, motion),
                **(vio or {}),
            },
        }
    )
    log = fly(o, seed=seed)
    k = slice(None, None, round(o.vio.rate_hz * DT))
    return vars(
        speed_statistic(*rpe_windows(log.vio_t_ns[k] * 1e-9, log.vio_x[k], log.vio_y[k])[1:])
    )


def summarize(rows: list[dict[str, Any]]) -> dict[str, str]:
    for r in rows:
        require(
            r["windows"] > 0 and all(np.isfinite(r[k]) for k in ("rpe_mean", "ratio", "rho")),
            "every flight has RPE windows and finite statistics",
        )

    def cell(key: str, fmt: str) -> str:
        v = np.array([r[key] for r in rows])
        if len(v) == 1:
            return format(v[0], fmt)
        return f"{format(v.mean(), fmt)} [{format(v.min(), fmt)}, {format(v.max(), fmt)}]"

    return {
        "windows": str(rows[0]["windows"]),
        "speed (m/s)": cell("speed_mean", ".2f"),
        "RPE mean (m)": cell("rpe_mean", ".4f"),
        "fast/slow": cell("ratio", ".2f"),
        "rho": cell("rho", ".2f"),
    }


def print_table(table: list[tuple[str, str, dict[str, str]]]) -> None:
    head = ["flight", "source", "windows", "speed (m/s)", "RPE mean (m)", "fast/slow", "rho"]
    cells = [[a, b, *c.values()] for a, b, c in table]
    width = [max(len(h), *(len(r[i]) for r in cells)) for i, h in enumerate(head)]
    print(" | ".join(h.ljust(w) for h, w in zip(head, width, strict=True)))
    print("-|-".join("-" * w for w in width))
    for r in cells:
        print(" | ".join(c.ljust(w) for c, w in zip(r, width, strict=True)))


SCALES = (1.0, 0.6, 0.55, 0.5, 0.45, 0.4, 0.35, 0.3, 0.25, 0.2)


def scan() -> None:
    from qsls.pipeline.sim.vio import RIDGE_VELOCITY_SCALE, VioEmulator, VioParams, scaled_ridges

    seeds = range(3)
    with tempfile.TemporaryDirectory() as tmp:
        real = [real_row(name, Path(tmp))["ratio"] for name in PAIRS]
    lo, hi = round(min(real), 2), round(max(real), 2)  # the real range, as the table shows it
    truths = {label: truth_states(name) for label, name in TRUTHS.items()}
    table: list[tuple[str, str, dict[str, str]]] = []
    passing = []
    for scale in SCALES:
        ridges = [r.model_dump() for r in scaled_ridges(scale, RIDGE_VELOCITY_SCALE)]
        vio = {"ridges": ridges}
        lip = VioEmulator(VioParams.model_validate(vio), 0).lipschitz
        ratios = []
        for label, truth in truths.items():
            rows = [emulated_row(truth, True, s, vio) for s in seeds]
            ratios += [r["ratio"] for r in rows]
            table.append((f"{label} truth", f"scale {scale}, L {lip:.3f}", summarize(rows)))
        for perception in ("regular", "degraded"):
            rows = [sim_row(True, s, perception, True, vio) for s in seeds]
            ratios += [r["ratio"] for r in rows]
            table.append((f"sim figure8 ({perception})", f"scale {scale}, L {lip:.3f}",
                          summarize(rows)))  # fmt: skip
        inside = all(lo <= r <= hi for r in ratios)
        print(f"scale {scale}: every seed's ratio in [{lo}, {hi}]: {inside}", flush=True)
        if inside:
            passing.append(scale)
    print_table(table)
    print(f"\nscales with every seed of every emulated flight in the real range: {passing}")
    if passing:
        print(f"the middle one (the smaller of two): {sorted(passing)[(len(passing) - 1) // 2]}")


def main() -> None:
    if "--scan" in sys.argv:
        scan()
        return
    folders = [Path(a) for a in sys.argv[1:] if not a.startswith("--")]
    if folders:
        print_table([(str(f), "ingested", summarize([flight_row(f)])) for f in folders])
        return
    smoke = requested()
    seeds = range(1 if smoke else 2 if "--quick" in sys.argv else 5)
    laps = 1 if smoke else 6
    if not REAL.is_dir():
        sys.exit(f"{REAL} not found: the real pairs are needed for this benchmark")
    start = time.perf_counter()
    table: list[tuple[str, str, dict[str, str]]] = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, (_, ratio, rho) in PAIRS.items():
            table.append((name, "real VIO", summarize([real_row(name, Path(tmp))])))
            table[-1][2]["fast/slow"] += f" (issue: {ratio:.2f})"
            table[-1][2]["rho"] += f" (issue: {rho:.2f})"
    for label, name in TRUTHS.items():
        truth = truth_states(name)
        for motion in (False, True):
            rows = [emulated_row(truth, motion, s) for s in seeds]
            table.append((f"{label} truth", f"emulator, motion {'on' if motion else 'off'}",
                          summarize(rows)))  # fmt: skip
    for perception, motion, bias in SIM_ROWS:
        rows = [sim_row(motion, s, perception, bias, laps=laps) for s in seeds]
        label = f"PD, {perception}, motion {'on' if motion else 'off'}"
        table.append(("sim figure8", label + ("" if bias else ", bias off"), summarize(rows)))
    print_table(table)
    print(f"\n{len(seeds)} seeds per emulated row; {time.perf_counter() - start:.1f} s in all")


if __name__ == "__main__":
    main()
