"""Rotations, one place: quaternions ``[x, y, z, w]`` (ROS and scipy order), matrices, yaw.

A quaternion ``q`` of a child frame in its parent gives ``R(q)`` with ``v_parent = R(q) v_child``.
"""

from __future__ import annotations

import numpy as np


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """``R(q)`` of a quaternion ``(4,)`` -> ``(3, 3)``, or of quaternions ``(n, 4)`` -> ``(n, 3, 3)``
    (normalized first, like scipy)::

        R = [[1 - 2(y^2 + z^2), 2(xy - zw),       2(xz + yw)],
             [2(xy + zw),       1 - 2(x^2 + z^2), 2(yz - xw)],
             [2(xz - yw),       2(yz + xw),       1 - 2(x^2 + y^2)]]
    """
    q = np.asarray(q, dtype=float)
    if q.ndim == 1:  # the simulator's inner loop: a plain array is several times faster
        x, y, z, w = q / np.sqrt(q @ q)
        return np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
            ]
        )
    x, y, z, w = (q / np.linalg.norm(q, axis=1, keepdims=True)).T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=1,
    )


def gravity_in_body(q: np.ndarray) -> np.ndarray:
    """``g_b = R(q)^T e_z``, the third row of ``R(q)``, per quaternion ``(n, 4)`` -> ``(n, 3)``."""
    q = np.asarray(q, dtype=float)
    x, y, z, w = (q / np.linalg.norm(q, axis=1, keepdims=True)).T
    return np.column_stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)])


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """Quaternions ``(n, 4)`` (``w >= 0``) of rotation matrices ``(n, 3, 3)``."""
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(np.asarray(m, dtype=float)).as_quat()
    return np.where(q[:, 3:4] < 0, -q, q)


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a b`` of quaternions ``(n, 4)``, row by row."""
    ax, ay, az, aw = a.T
    bx, by, bz, bw = b.T
    return np.stack(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ],
        axis=1,
    )


def rotvec_quat(phi: np.ndarray) -> np.ndarray:
    """Quaternions ``exp(phi / 2)`` of rotation vectors ``(n, 3)``."""
    ang = np.linalg.norm(phi, axis=1, keepdims=True)
    half = 0.5 * ang
    k = np.where(ang > 1e-12, np.sin(half) / np.where(ang > 1e-12, ang, 1.0), 0.5)
    return np.hstack([phi * k, np.cos(half)])


def rot_z(psi: float) -> np.ndarray:
    """Rotation by ``psi`` about z."""
    c, s = np.cos(psi), np.sin(psi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def body_to_world(q: np.ndarray, v_body: np.ndarray) -> np.ndarray:
    """``R(q) v`` per sample: a child-frame (body) vector in the parent (world) frame."""
    return np.einsum("nij,nj->ni", quat_to_matrix(q), v_body)
