"""SO(3) for the filter and the camera: ``skew``, ``exp``, ``log`` and the camera mount.

``exp(phi) = I + sin(a)/a [phi]x + (1 - cos(a))/a^2 [phi]x^2`` with ``a = ||phi||``
(Rodrigues); ``log`` its inverse on rotations of angle below pi.
"""

from __future__ import annotations

import math

import numpy as np


def skew(v: np.ndarray) -> np.ndarray:
    """``[v]x`` with ``[v]x w = v x w``."""
    x, y, z = float(v[0]), float(v[1]), float(v[2])
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def so3_exp(phi: np.ndarray) -> np.ndarray:
    """Rodrigues' formula (module docstring); second order below 1e-8 rad. Written out on
    floats with ``[phi]x^2 = phi phi^T - a^2 I`` (one array made, not five: the filter calls
    it once per IMU sample)."""
    x, y, z = float(phi[0]), float(phi[1]), float(phi[2])
    a2 = x * x + y * y + z * z
    if a2 < 1e-16:
        s, c = 1.0, 0.5
    else:
        a = math.sqrt(a2)
        s, c = math.sin(a) / a, (1.0 - math.cos(a)) / a2
    return np.array(
        [
            [1.0 + c * (x * x - a2), c * x * y - s * z, c * x * z + s * y],
            [c * x * y + s * z, 1.0 + c * (y * y - a2), c * y * z - s * x],
            [c * x * z - s * y, c * y * z + s * x, 1.0 + c * (z * z - a2)],
        ]
    )


def so3_exp_many(phi: np.ndarray) -> np.ndarray:
    """:func:`so3_exp` of each row of ``phi`` (N, 3): rotations (N, 3, 3)."""
    a2 = np.einsum("ni,ni->n", phi, phi)
    small = a2 < 1e-16
    a = np.sqrt(np.where(small, 1.0, a2))
    s = np.where(small, 1.0, np.sin(a) / a)
    c = np.where(small, 0.5, (1.0 - np.cos(a)) / np.where(small, 1.0, a2))
    x, y, z = phi[:, 0], phi[:, 1], phi[:, 2]
    out = c[:, None, None] * (phi[:, :, None] * phi[:, None, :])
    idx = np.arange(3)
    out[:, idx, idx] += (1.0 - c * a2)[:, None]
    sz, sy, sx = s * z, s * y, s * x
    out[:, 0, 1] -= sz
    out[:, 1, 0] += sz
    out[:, 0, 2] += sy
    out[:, 2, 0] -= sy
    out[:, 1, 2] -= sx
    out[:, 2, 1] += sx
    return out


def so3_log(r: np.ndarray) -> np.ndarray:
    """The rotation vector ``phi`` with ``exp(phi) = r`` (angle below pi)."""
    c = max(-1.0, min(1.0, 0.5 * (float(r[0, 0] + r[1, 1] + r[2, 2]) - 1.0)))
    a = math.acos(c)
    w = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    if a < 1e-7:
        return 0.5 * w
    return (a / (2.0 * math.sin(a))) * w


def camera_in_body(pitch_deg: float) -> np.ndarray:
    """``R_bc`` of a camera looking down (body -z) with its optical axis tilted ``pitch_deg``
    towards body +x; image x to the body's -y (right, seen from above), image y to the
    back. Columns: the camera's x, y, z axes in the body frame."""
    t = math.radians(pitch_deg)
    z = np.array([math.sin(t), 0.0, -math.cos(t)])  # optical axis
    x = np.array([0.0, -1.0, 0.0])
    y = np.cross(z, x)
    return np.column_stack([x, y, z])


def matrix_quat(r: np.ndarray) -> np.ndarray:
    """Quaternion ``[x, y, z, w]`` (``w >= 0``) of one rotation matrix (Shepperd's method:
    the largest of ``w, x, y, z`` is taken from the trace or a diagonal element first)."""
    m00, m11, m22 = float(r[0, 0]), float(r[1, 1]), float(r[2, 2])
    tr = m00 + m11 + m22
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [(r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s, 0.25 * s]
    elif m00 > m11 and m00 > m22:
        s = 2.0 * math.sqrt(1.0 + m00 - m11 - m22)
        q = [0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s, (r[2, 1] - r[1, 2]) / s]
    elif m11 > m22:
        s = 2.0 * math.sqrt(1.0 + m11 - m00 - m22)
        q = [(r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s, (r[0, 2] - r[2, 0]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m22 - m00 - m11)
        q = [(r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s, (r[1, 0] - r[0, 1]) / s]
    out = np.array(q, dtype=float)
    out /= math.sqrt(float(out @ out))
    return -out if out[3] < 0 else out
