"""The IMU: gyroscope and accelerometer samples from the vehicle's true motion.

One sample per physics step ``[t_i, t_i + h]`` (200 Hz by default), the increments a
delta-angle / delta-velocity IMU reports, expressed as rates in the body frame at ``t_i``::

    omega_i = log(R_i^T R_{i+1}) / h
    a_i     = R_i^T ((v_{i+1} - v_i) / h - g),         g = (0, 0, -9.81)

(so that integrating them exactly, as the filter does, reproduces the true attitude and
velocity at every step). Measurements add white noise of density ``sigma`` (discrete std
``sigma / sqrt(h)``) and a bias that random-walks with density ``sigma_w`` (discrete step std
``sigma_w sqrt(h)``), started from ``N(0, bias0^2)``::

    omega_m = omega + b_g + n_g,   a_m = a + b_a + n_a,   b_{k+1} = b_k + sigma_w sqrt(h) w_k
"""

from __future__ import annotations

import math

import numpy as np

from qsls.pipeline.sim.camera.geometry import so3_log
from qsls.pipeline.sim.camera.options import CameraOptions


def true_rates(
    r0: np.ndarray, r1: np.ndarray, v0: np.ndarray, v1: np.ndarray, h: float, g: float
) -> tuple[np.ndarray, np.ndarray]:
    """``(omega, a)`` of the module docstring over one step of ``h`` seconds."""
    omega = so3_log(r0.T @ r1) / h
    acc = r0.T @ ((v1 - v0) / h + np.array([0.0, 0.0, g]))
    return omega, acc


class Imu:
    """Noisy, biased gyroscope and accelerometer (module docstring), seeded."""

    def __init__(self, cam: CameraOptions, h: float, seed_seq: np.random.SeedSequence) -> None:
        self.on = cam.imu_noise
        self.rng = np.random.default_rng(seed_seq)
        self.h = h
        self.sd_g = cam.gyro_noise / math.sqrt(h)
        self.sd_a = cam.accel_noise / math.sqrt(h)
        self.walk_g = cam.gyro_walk * math.sqrt(h)
        self.walk_a = cam.accel_walk * math.sqrt(h)
        z = self.rng.standard_normal(6)
        self.bias_g = cam.gyro_bias0 * z[:3] if self.on else np.zeros(3)
        self.bias_a = cam.accel_bias0 * z[3:] if self.on else np.zeros(3)
        # noise drawn in blocks (one call per 256 samples, not per sample)
        self._block = np.zeros((0, 12))
        self._k = 0

    def measure(self, omega: np.ndarray, acc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(omega_m, a_m)`` of one step; advances the biases."""
        if not self.on:
            return omega, acc
        if self._k >= len(self._block):
            self._block = self.rng.standard_normal((256, 12))
            self._k = 0
        z = self._block[self._k]
        self._k += 1
        wm = omega + self.bias_g + self.sd_g * z[0:3]
        am = acc + self.bias_a + self.sd_a * z[3:6]
        self.bias_g = self.bias_g + self.walk_g * z[6:9]
        self.bias_a = self.bias_a + self.walk_a * z[9:12]
        return wm, am
