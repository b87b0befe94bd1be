"""The paper's input as a force, both ways: what an attitude setpoint and a collective thrust
command, and back (docs/model.md#signs-paper-b-against-a-z-up-body-frame, docs/vehicle.md).

The paper's linear model reads the absolute input ``u = [pitch, roll, thrust]`` as the force
the rotors must give (z-up world, newtons)::

    f = [-m g pitch, m g roll, thrust]                      (demanded_force)

A vehicle flies ``f`` as an attitude (body z along ``f``) and a collective thrust ``|f|``
(:func:`qsls.pipeline.export.attitude.thrust_attitude`, with its limits). A recorded command
(an attitude ``q`` and a thrust ``T`` normalized as PX4's, hover at ``T_hover``) comes back
to the input through the inverse::

    thrust_N = m g T / T_hover,   f = thrust_N R(q) e3,
    u = [-f_x / (m g), f_y / (m g), f_z]                    (input_from_force)

exact wherever the command was not limited (the tests round-trip it to 1e-12); the yaw of
``q`` does not enter (``R(q) e3`` is the body z axis).
"""

from __future__ import annotations

import numpy as np

from qsls.pipeline.core.plant import GRAVITY
from qsls.pipeline.core.rotations import quat_to_matrix


def absolute_input(u: np.ndarray, acc: np.ndarray, mass: float, g: float = GRAVITY) -> np.ndarray:
    """``[pitch, roll, thrust]`` (n, 3): hover + feedforward of ``acc`` (n, 3) + ``u`` (n, 3)."""
    u = np.atleast_2d(np.asarray(u, dtype=float))
    acc = np.atleast_2d(np.asarray(acc, dtype=float))
    return np.column_stack(
        [u[:, 0] - acc[:, 0] / g, u[:, 1] + acc[:, 1] / g, mass * (g + acc[:, 2]) + u[:, 2]]
    )


def demanded_force(u_abs: np.ndarray, mass: float, g: float = GRAVITY) -> np.ndarray:
    """``f = m (a_ref + a_u + g e3)`` (n, 3) before any limit, from the absolute paper input
    ``[pitch, roll, thrust]`` (:func:`absolute_input`): ``[-m g pitch, m g roll, thrust]``."""
    u_abs = np.atleast_2d(np.asarray(u_abs, dtype=float))
    return np.column_stack([-mass * g * u_abs[:, 0], mass * g * u_abs[:, 1], u_abs[:, 2]])


def input_from_force(f: np.ndarray, mass: float, g: float = GRAVITY) -> np.ndarray:
    """The absolute paper input (n, 3) of the force ``f`` (n, 3): the inverse of
    :func:`demanded_force`, ``[-f_x / (m g), f_y / (m g), f_z]``."""
    f = np.atleast_2d(np.asarray(f, dtype=float))
    return np.column_stack([-f[:, 0] / (mass * g), f[:, 1] / (mass * g), f[:, 2]])


def thrust_newtons(
    normalized: np.ndarray, hover: np.ndarray | float, mass: float, g: float = GRAVITY
) -> np.ndarray:
    """``m g T / T_hover``: a normalized thrust (PX4's ``|thrust_body|``, mavros' scaled
    thrust) in newtons, linear through hover (PX4 linearizes its motors' curve with
    ``THR_MDL_FAC``, so the setpoint is proportional to the force)."""
    return mass * g * np.asarray(normalized, dtype=float) / np.asarray(hover, dtype=float)


def force_from_attitude(q: np.ndarray, thrust: np.ndarray) -> np.ndarray:
    """``f = thrust R(q) e3`` (n, 3): the force of attitudes ``q`` ([x, y, z, w], body in the
    z-up world) and collective thrusts ``thrust`` (n,) in newtons."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    z_body = quat_to_matrix(q)[:, :, 2]
    return z_body * np.asarray(thrust, dtype=float).reshape(-1, 1)


def input_from_attitude(
    q: np.ndarray, normalized: np.ndarray, hover: np.ndarray | float, mass: float,
    g: float = GRAVITY,
) -> np.ndarray:  # fmt: skip
    """The absolute paper input (n, 3) of recorded attitude setpoints ``q`` and normalized
    thrusts (module docstring)."""
    thrust = thrust_newtons(normalized, hover, mass, g)
    return input_from_force(force_from_attitude(q, thrust), mass, g)
