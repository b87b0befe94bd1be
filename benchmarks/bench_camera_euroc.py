"""The camera loop on EuRoC's real trajectories, beside the real VIO estimates of the same flights.

    python benchmarks/bench_camera_euroc.py           # V1_02 and MH_04, whole flights
    python benchmarks/bench_camera_euroc.py --quick   # their first 30 s
    python benchmarks/bench_camera_euroc.py --smoke   # their first 3 s, seed 0 (smokemode.py)

The ground-truth motion of V1_02 (``euroc_v102/groundtruth.csv``, 200 Hz) and MH_04
(``euroc_mh04_rpg/groundtruth_tum.txt``, 200 Hz) from ``../shared/data/real`` is replayed
through the camera loop (:func:`qsls.pipeline.sim.camera.loop.replay`: IMU from the motion,
frames rendered over the seeded textured floor, MSCKF), regular light, seeds 0..2. EuRoC's
IMU frame has its x axis up and z forward; the vehicle frame the camera is mounted on is
``(x, y, z) = (z_imu, -y_imu, x_imu)``. The floor is put 0.8 m below the lowest point of the
flight (the real rooms' floors are not in the files).

Both estimates, ours and the real VIO files' (``estimate_tum.txt``: V1_02 from evo's test
data, MH_04 from rpg_trajectory_evaluation), get the same treatment: sampled at the real
estimate's times (real: after the README's clock offset), SE(3)-aligned to the ground truth
(Kabsch on centred positions: ``scipy.spatial.transform.Rotation.align_vectors``), then ATE
RMS and the mean 1 s RPE (:func:`qsls.pipeline.evaluate.rpe.rpe_windows`, world frame).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
from smokemode import requested, require

REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
FLIGHTS = {  # name: (truth file, estimate file, clock offset added to truth stamps)
    "V1_02": ("euroc_v102/groundtruth.csv", "euroc_v102/estimate_tum.txt", 0.007),
    "MH_04": ("euroc_mh04_rpg/groundtruth_tum.txt", "euroc_mh04_rpg/estimate_tum.txt", 0.034),
}
IMU_TO_VEHICLE = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])
"""Columns: the vehicle's x, y, z axes in EuRoC's IMU frame."""


def load_truth(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(t s, p (n, 3), q xyzw (n, 4))`` of a EuRoC csv or a TUM file."""
    if path.suffix == ".csv":
        a = np.loadtxt(path, delimiter=",", comments="#")
        return a[:, 0] * 1e-9, a[:, 1:4], a[:, [5, 6, 7, 4]]
    a = np.loadtxt(path, comments="#")
    return a[:, 0], a[:, 1:4], a[:, 4:8]


def load_estimate(path: Path) -> tuple[np.ndarray, np.ndarray]:
    a = np.loadtxt(path, comments="#")
    t, keep = np.unique(a[:, 0], return_index=True)  # duplicate stamps dropped
    return t, a[keep, 1:4]


def aligned(est: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """``est`` moved by the rotation and translation that best fit it to ``truth``."""
    from scipy.spatial.transform import Rotation

    me, mt = est.mean(axis=0), truth.mean(axis=0)
    rot, _ = Rotation.align_vectors(truth - mt, est - me)
    return rot.apply(est - me) + mt


def metrics(t: np.ndarray, est: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    from qsls.pipeline.evaluate.rpe import rpe_windows

    a = aligned(est, truth)
    ate = float(np.sqrt(np.mean(np.sum((a - truth) ** 2, axis=1))))
    _, _, rpe = rpe_windows(t, truth, a, 1.0)
    return ate, float(rpe.mean())


def interp_positions(t_from: np.ndarray, p: np.ndarray, t_to: np.ndarray) -> np.ndarray:
    return np.column_stack([np.interp(t_to, t_from, p[:, i]) for i in range(3)])


def main(argv: list[str]) -> None:
    from qsls.pipeline.core.rotations import matrix_to_quat, quat_to_matrix
    from qsls.pipeline.sim.camera.loop import replay
    from qsls.pipeline.sim.camera.options import CameraOptions

    if not REAL.is_dir():
        print(f"no real data at {REAL}: nothing to compare")
        return
    smoke = requested(argv)
    quick = "--quick" in argv or smoke
    first_s = 3.0 if smoke else 30.0
    seeds = (0,) if smoke else (0, 1, 2)
    head = (
        f"{'flight':8s} {'estimate':30s} {'ATE RMS (m)':>12s} {'1 s RPE (m)':>12s} {'CPU (s)':>8s}"
    )
    print(head)
    print("-" * len(head))
    for name, (truth_file, est_file, offset) in FLIGHTS.items():
        t, p, q = load_truth(REAL / truth_file)
        te, pe = load_estimate(REAL / est_file)
        t_true = t + offset  # on the estimate's clock
        keep = (te >= t_true[0]) & (te <= t_true[-1])
        te, pe = te[keep], pe[keep]
        if quick:  # the first 30 s with a real estimate
            sel = (t_true >= te[0] - 1.0) & (t_true <= te[0] + first_s)
            t, p, q, t_true = t[sel], p[sel], q[sel], t_true[sel]
            te, pe = te[te <= t_true[-1]], pe[te <= t_true[-1]]
        ate, rpe = metrics(te, pe, interp_positions(t_true, p, te))
        require(np.isfinite([ate, rpe]).all(), f"{name}: the real estimate's ATE and RPE")
        print(
            f"{name:8s} {'real VIO (' + est_file.split('/')[0] + ')':30s} {ate:12.3f} {rpe:12.4f} {'-':>8s}"
        )
        # a uniform 200 Hz grid (the files have jitter of a few microseconds)
        rel = np.arange(int((t[-1] - t[0]) * 200.0)) / 200.0
        grid = t[0] + rel
        pg = interp_positions(t, p, grid)
        rot = quat_to_matrix(q)
        idx = np.clip(np.searchsorted(t, grid), 0, len(t) - 1)
        qg = matrix_to_quat(rot[idx] @ IMU_TO_VEHICLE)
        cam = CameraOptions(ground_z=float(p[:, 2].min()) - 0.8)
        rows = []
        for seed in seeds:
            c0 = time.process_time()
            est, _, loop = replay(cam, 1.0, 1.0, seed, rel, pg, qg)
            cpu = time.process_time() - c0
            at = te - offset  # the real estimate's times on the truth clock
            inside = (at >= grid[0]) & (at <= grid[-1])
            pe_ours = interp_positions(grid, est[:, :3], at[inside])
            pt = interp_positions(grid, pg, at[inside])
            ate_o, rpe_o = metrics(at[inside], pe_ours, pt)
            rows.append((ate_o, rpe_o, cpu))
            require(np.isfinite([ate_o, rpe_o]).all(), f"{name} seed {seed}: our ATE and RPE")
            print(
                f"{'':8s} {f'camera loop, seed {seed}':30s} {ate_o:12.3f} {rpe_o:12.4f} {cpu:8.1f}"
                f"  resets {len(loop.resets)}"
            )
        r = np.array(rows)
        print(
            f"{'':8s} {f'camera loop, mean of {len(rows)}':30s} {r[:, 0].mean():12.3f} {r[:, 1].mean():12.4f}\n"
        )


if __name__ == "__main__":
    main(sys.argv[1:])
