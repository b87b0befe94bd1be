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


def world_to_body(q: np.ndarray, v_world: np.ndarray) -> np.ndarray:
    """``R(q)^T v`` per sample: a parent-frame (world) vector in the child (body) frame, the
    inverse of :func:`body_to_world`."""
    return np.einsum("nji,nj->ni", quat_to_matrix(q), v_world)


# --------------------------------------------------------------------------- NED/FRD <-> ENU/FLU
# PX4 (and aerospace) frames: world NED (x north, y east, z down), body FRD (x forward, y right,
# z down), quaternions ``[w, x, y, z]``; the project's: world ENU (x east, y north, z up), body
# FLU (x forward, y left, z up), quaternions ``[x, y, z, w]``.

_S = float(np.sqrt(0.5))
Q_ENU_NED = np.array([_S, _S, 0.0, 0.0])
"""``q(ENU<-NED)`` ``[x, y, z, w]``: a half turn about ``(1, 1, 0) / sqrt(2)``,
``R = [[0, 1, 0], [1, 0, 0], [0, 0, -1]]`` (its own inverse)."""
Q_FRD_FLU = np.array([1.0, 0.0, 0.0, 0.0])
"""``q(FRD<-FLU)`` ``[x, y, z, w]``: a half turn about x, ``R = diag(1, -1, -1)``."""


def ned_to_enu(v: np.ndarray) -> np.ndarray:
    """World vectors ``(..., 3)`` NED -> ENU: ``[v_n[1], v_n[0], -v_n[2]]`` (east = NED's y,
    north = NED's x, up = -down); the same map takes ENU to NED (its own inverse)."""
    v = np.asarray(v, dtype=float)
    return np.stack([v[..., 1], v[..., 0], -v[..., 2]], axis=-1)


def frd_to_flu(v: np.ndarray) -> np.ndarray:
    """Body vectors ``(..., 3)`` FRD -> FLU: ``[v_x, -v_y, -v_z]`` (its own inverse)."""
    v = np.asarray(v, dtype=float)
    return np.stack([v[..., 0], -v[..., 1], -v[..., 2]], axis=-1)


def wxyz_to_xyzw(q: np.ndarray) -> np.ndarray:
    """Quaternions ``(..., 4)`` from PX4's ``[w, x, y, z]`` order to ``[x, y, z, w]``."""
    q = np.asarray(q, dtype=float)
    return np.concatenate([q[..., 1:4], q[..., 0:1]], axis=-1)


def frd_ned_to_flu_enu(q: np.ndarray) -> np.ndarray:
    """Attitudes ``(..., 4)`` ``[x, y, z, w]`` of an FRD body in NED -> of the FLU body in ENU.

    ``q_enu_flu = q(ENU<-NED) q_ned_frd q(FRD<-FLU)`` (:data:`Q_ENU_NED`, :data:`Q_FRD_FLU`),
    i.e. ``R_enu_flu = P R_ned_frd D`` with ``P = [[0, 1, 0], [1, 0, 0], [0, 0, -1]]`` and
    ``D = diag(1, -1, -1)``. Multiplied out, with ``(x, y, z, w)`` the NED quaternion::

        q_enu_flu = [x + y, x - y, w - z, w + z] / sqrt(2)

    (the product itself is the negative of this: the same rotation). Heading north in NED
    (the identity) is yaw ``pi/2`` in ENU; heading east (yaw_ned ``pi/2``) is the identity.
    Not normalized beyond what the input is (the map is orthogonal: norms are kept); NaN
    stays NaN."""
    q = np.asarray(q, dtype=float)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    out = np.empty(q.shape)  # column by column: one temporary at a time
    np.add(x, y, out=out[..., 0])
    np.subtract(x, y, out=out[..., 1])
    np.subtract(w, z, out=out[..., 2])
    np.add(w, z, out=out[..., 3])
    out *= _S
    return out


def yaw_ned_to_enu(yaw: np.ndarray) -> np.ndarray:
    """Headings NED (rad from north, clockwise seen from above) -> ENU (rad from east,
    counter-clockwise about z up): ``pi/2 - yaw``, wrapped to ``[-pi, pi)``; NaN stays NaN."""
    y = np.pi / 2 - np.asarray(yaw, dtype=float)
    return (y + np.pi) % (2 * np.pi) - np.pi


def yaw_quat(yaw: np.ndarray) -> np.ndarray:
    """Quaternions ``(n, 4)`` ``[x, y, z, w]`` of rotations by ``yaw`` ``(n,)`` about z:
    ``[0, 0, sin(yaw / 2), cos(yaw / 2)]``."""
    h = 0.5 * np.asarray(yaw, dtype=float)
    zero = np.zeros_like(h)
    return np.stack([zero, zero, np.sin(h), np.cos(h)], axis=-1)
