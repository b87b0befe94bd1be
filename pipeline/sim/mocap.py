"""Motion capture: the true pose at 100-200 Hz with millimetre noise.

The noise model is RotorPy's ``MotionCapture`` (``rotorpy/sensors/external_mocap.py``):
additive Gaussian position noise and an attitude perturbation ``q (+) exp(delta_phi)`` with
``delta_phi`` Gaussian, here given as standard deviations per sample and drawn from a seeded
generator (RotorPy's sensor uses the global ``np.random``), vectorized over the whole flight.
The pose at a sample time between two physics steps is interpolated like the VIO samples
(cubic Hermite position, normalized linear quaternion).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qsls.pipeline.core.rotations import quat_mul, rotvec_quat
from qsls.pipeline.core.units import NS
from qsls.pipeline.sim.options import MocapOptions


@dataclass(frozen=True)
class MocapSamples:
    t_ns: np.ndarray  # (n,) simulation time
    position: np.ndarray  # (n, 3)
    orientation: np.ndarray  # (n, 4) xyzw
    true_position: np.ndarray  # (n, 3)


def interpolate_truth(
    t_ns: np.ndarray, x: np.ndarray, q: np.ndarray, query_ns: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """True ``(p, v, q)`` at ``query_ns`` from states on a uniform physics grid ``t_ns``."""
    h_ns = int(t_ns[1] - t_ns[0]) if len(t_ns) > 1 else 1
    h = h_ns / NS
    rel = np.asarray(query_ns, dtype=np.int64) - int(t_ns[0])
    i = np.clip(rel // h_ns, 0, len(t_ns) - 2)
    a = ((rel - i * h_ns) / h_ns)[:, None]
    p0, v0, p1, v1 = x[i, :3], x[i, 3:], x[i + 1, :3], x[i + 1, 3:]
    a2, a3 = a * a, a * a * a
    p = (
        (2 * a3 - 3 * a2 + 1) * p0
        + (a3 - 2 * a2 + a) * h * v0
        + (-2 * a3 + 3 * a2) * p1
        + (a3 - a2) * h * v1
    )
    v = v0 + a * (v1 - v0)
    q0, q1 = q[i], q[i + 1]
    q1 = np.where(((q0 * q1).sum(axis=1) < 0)[:, None], -q1, q1)
    qq = q0 + a * (q1 - q0)
    qq /= np.linalg.norm(qq, axis=1, keepdims=True)
    return p, v, qq


def sample_mocap(
    options: MocapOptions,
    t_ns: np.ndarray,
    x: np.ndarray,
    q: np.ndarray,
    rng: np.random.Generator,
) -> MocapSamples:
    """Noisy poses every ``1 / rate_hz`` over the flight (truth on the physics grid)."""
    period = round(NS / options.rate_hz)
    times = np.arange(0, int(t_ns[-1]) + 1, period, dtype=np.int64)
    p, _, qq = interpolate_truth(t_ns, x, q, times)
    n = len(times)
    noise_p = rng.standard_normal((n, 3)) * options.position_noise
    noise_q = rng.standard_normal((n, 3)) * options.attitude_noise
    q_meas = quat_mul(qq, rotvec_quat(noise_q))
    return MocapSamples(t_ns=times, position=p + noise_p, orientation=q_meas, true_position=p)
