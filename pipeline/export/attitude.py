"""The controller's ``u`` plus the reference's feedforward -> collective thrust and attitude.

DESIGN.md, Model and Signs. The absolute paper input is hover plus feedforward plus ``u``::

    pitch = u0 - a_x / g,   roll = u1 + a_y / g,   thrust = m (g + a_z) + u2

(``a`` the reference's acceleration, world frame, z up). In a z-up world a right-handed
rotation ``theta`` about body y tilts the thrust toward +x, so ``theta = -pitch`` and
``phi = -roll`` (about body x), yaw 0, ``R = R_y(theta) R_x(phi)``; as a quaternion
``[x, y, z, w]`` (ROS order)::

    q = [cos(theta/2) sin(phi/2), sin(theta/2) cos(phi/2), -sin(theta/2) sin(phi/2),
         cos(theta/2) cos(phi/2)]

which is :func:`qsls.pipeline.sim.vehicle.paper_to_ctatt` (RotorPy's ``cmd_ctatt``), the input
of mavros ``AttitudeTarget`` (ENU world, normalized thrust), PX4's offboard attitude
setpoint (after mavros's ENU->NED conversion) and a Crazyflie's out-of-tree controller.
The body z axis is ``R e3``, so the tilt from vertical is ``acos(cos(theta) cos(phi))``.

This module holds the formula three times, side by side: numpy (:func:`thrust_attitude`,
for replay and the tests), C (:func:`c_function`) and stdlib Python (:data:`PY_FUNCTION`).
"""

from __future__ import annotations

import numpy as np

from qsls.pipeline.core.plant import GRAVITY


def absolute_input(u: np.ndarray, acc: np.ndarray, mass: float, g: float = GRAVITY) -> np.ndarray:
    """``[pitch, roll, thrust]`` (n, 3): hover + feedforward of ``acc`` (n, 3) + ``u`` (n, 3)."""
    u = np.atleast_2d(np.asarray(u, dtype=float))
    acc = np.atleast_2d(np.asarray(acc, dtype=float))
    return np.column_stack(
        [u[:, 0] - acc[:, 0] / g, u[:, 1] + acc[:, 1] / g, mass * (g + acc[:, 2]) + u[:, 2]]
    )


def thrust_attitude(u_abs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Collective thrust (n,) in newtons and quaternions ``[x, y, z, w]`` (n, 4)."""
    u_abs = np.atleast_2d(np.asarray(u_abs, dtype=float))
    th, ph = -0.5 * u_abs[:, 0], -0.5 * u_abs[:, 1]
    ct, st, cp, sp = np.cos(th), np.sin(th), np.cos(ph), np.sin(ph)
    q = np.column_stack([ct * sp, st * cp, -st * sp, ct * cp])
    return u_abs[:, 2].copy(), q


def tilt_rad(u_abs: np.ndarray) -> np.ndarray:
    """Angle (n,) between the commanded body z axis and world z: ``acos(cos(pitch) cos(roll))``."""
    u_abs = np.atleast_2d(np.asarray(u_abs, dtype=float))
    return np.arccos(np.clip(np.cos(u_abs[:, 0]) * np.cos(u_abs[:, 1]), -1.0, 1.0))


def c_function(prefix: str, real: str, float_math: bool) -> str:
    """The C helper ``PREFIX_attitude(u, acc_ref, &thrust, q)`` (body of the .c file)."""
    m = prefix.upper()
    cos, sin = ("cosf", "sinf") if float_math else ("cos", "sin")
    half = "0.5f" if float_math else "0.5"
    return f"""void {prefix}_attitude(const {real} u[{m}_NU], const {real} acc_ref[3],
                {real} *thrust, {real} q[4])
{{
    const {real} pitch = u[0] - acc_ref[0] / {m}_GRAVITY;
    const {real} roll = u[1] + acc_ref[1] / {m}_GRAVITY;
    const {real} th = -{half} * pitch; /* theta / 2, theta = -pitch about body y */
    const {real} ph = -{half} * roll;  /* phi / 2, phi = -roll about body x */
    const {real} ct = {cos}(th), st = {sin}(th), cp = {cos}(ph), sp = {sin}(ph);
    *thrust = {m}_MASS * ({m}_GRAVITY + acc_ref[2]) + u[2];
    q[0] = ct * sp;
    q[1] = st * cp;
    q[2] = -st * sp;
    q[3] = ct * cp;
}}
"""


PY_FUNCTION = '''
def attitude(u, acc_ref):
    """``(thrust [N], q [x, y, z, w])`` from ``u`` and the reference acceleration (z-up world).

    pitch = u0 - a_x / g, roll = u1 + a_y / g, thrust = m (g + a_z) + u2;
    theta = -pitch about body y, phi = -roll about body x, yaw 0.
    """
    pitch = u[0] - acc_ref[0] / GRAVITY
    roll = u[1] + acc_ref[1] / GRAVITY
    th, ph = -0.5 * pitch, -0.5 * roll
    ct, st, cp, sp = math.cos(th), math.sin(th), math.cos(ph), math.sin(ph)
    thrust = MASS * (GRAVITY + acc_ref[2]) + u[2]
    return thrust, [ct * sp, st * cp, -st * sp, ct * cp]
'''
