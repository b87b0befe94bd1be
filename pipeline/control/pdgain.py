"""The PD position controller in the paper's input convention.

Desired acceleration ``a = -Kp (p - p_ref) - Kd (v - v_ref)`` per axis, mapped through the
paper's ``B`` (``vx' = -g pitch``, ``vy' = +g roll``, ``vz' = thrust / m``)::

    u = [pitch, roll, thrust] = [-a_x / g, a_y / g, m a_z]

as deviations from hover, i.e. ``u = K (y - r)`` with the gain :func:`pd_gain` returns.
The synthesis stage uses ``K`` for the PD closed loop's responses (the imitation nominal)
and the simulator flies it.
"""

from __future__ import annotations

import numpy as np

from qsls.pipeline.core.config import Options
from qsls.pipeline.core.plant import GRAVITY


class PDGains(Options):
    """Per-axis proportional (1/s^2) and derivative (1/s) gains on position error."""

    kp: tuple[float, float, float] = (2.0, 2.0, 4.0)
    kd: tuple[float, float, float] = (2.2, 2.2, 3.0)


def pd_gain(gains: PDGains, mass: float, g: float = GRAVITY) -> np.ndarray:
    """``K`` (3x6) with ``u = K (y - r)``: the PD law in the paper's input coordinates."""
    kp = np.asarray(gains.kp, dtype=float)
    kd = np.asarray(gains.kd, dtype=float)
    accel = -np.hstack([np.diag(kp), np.diag(kd)])  # a = accel @ (y - r)
    to_input = np.diag([-1.0 / g, 1.0 / g, mass])
    return to_input @ accel
