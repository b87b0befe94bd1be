"""The controller's ``u`` plus the reference's feedforward -> collective thrust and attitude.

docs/model.md#signs-paper-b-against-a-z-up-body-frame. The paper's linear model reads ``u = [pitch, roll, thrust]``
(deviations from hover plus the reference's feedforward) as an acceleration
``a_u = [-g u0, g u1, u2 / m]`` (``vx' = -g pitch``, ``vy' = +g roll``). The command is the
exact (differential-flatness) map of the total acceleration ``a = a_ref + a_u``::

    f = m (a + g e3)                       (the force the rotors must give, N)
    thrust = |f|,   body z = f / |f|

with the limits applied in this order (:class:`AttitudeLimits`, multiples of hover ``m g``):
``f_z`` at least ``thrust_min m g cos(max_tilt)`` (the rotors only push up), the horizontal
part of ``f`` scaled down to ``|f_xy| <= f_z tan(max_tilt)``, then ``|f|`` clamped to
``[thrust_min, thrust_max] m g`` (a scaling, so the tilt stays within its limit).

Yaw: the heading ``psi`` (rad about world z, the caller's commanded yaw; 0 holds the world x
heading) is applied after the minimal tilt: ``q = q_z(psi) * q_tilt(e3 -> Rz(-psi) z_b)``,
with the minimal rotation taking ``e3`` to a unit ``n`` (``n_z > 0``)::

    q_tilt = [-n_y, n_x, 0, 1 + n_z] / sqrt(2 (1 + n_z))          ([x, y, z, w], ROS order)

For small angles and ``psi = 0`` this is the simulator's small-angle map
(:func:`qsls.pipeline.sim.vehicle.paper_to_ctatt`: ``theta = -pitch`` about body y,
``phi = -roll`` about body x, thrust ``m (g + a_z) + u2``); the exact map's thrust is
``m |a + g e3|``, e.g. 1.3 % more at 1.6 m/s^2 of horizontal acceleration.

The thrust is in newtons. mavros ``AttitudeTarget`` takes a normalized thrust: replay writes
``hover_thrust * thrust / (m g)`` (linear in thrust; ``hover_thrust`` is the vehicle's hover
throttle, PX4's ``MPC_THR_HOVER``).

This module holds the formula three times, side by side: numpy (:func:`thrust_attitude`,
for replay and the tests), C (:func:`c_function`) and stdlib Python (:func:`py_function`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydantic import Field, field_validator

from qsls.pipeline.core.attitude import absolute_input, demanded_force
from qsls.pipeline.core.config import Options
from qsls.pipeline.core.plant import GRAVITY


@dataclass(frozen=True)
class AttitudeLimits:
    """Saturation of the exported attitude command."""

    max_tilt_deg: float = 30.0
    """Largest angle between body z and world z (deg)."""
    thrust_min: float = 0.5
    """Smallest collective thrust, in multiples of hover ``m g``."""
    thrust_max: float = 2.0
    """Largest collective thrust, in multiples of hover ``m g``."""

    def describe(self) -> str:
        return (
            f"tilt <= {self.max_tilt_deg:g} deg, thrust in [{self.thrust_min:g}, "
            f"{self.thrust_max:g}] x m g"
        )


def check_thrust_limits(v: tuple[float, float]) -> tuple[float, float]:
    """``0 < low < 1 < high``: hover itself must be commandable."""
    lo, hi = v
    if not 0 < lo < 1 < hi:
        raise ValueError(f"thrust limits must satisfy 0 < low < 1 < high (x m g), got {lo}, {hi}")
    return v


class LimitOptions(Options):
    """The attitude helper's saturation as options (``qsls export`` and ``qsls replay``)."""

    tilt_limit_deg: float = Field(AttitudeLimits.max_tilt_deg, gt=0, lt=90)
    """The attitude helper's largest tilt from vertical (deg), stated in the header."""
    thrust_limits: tuple[float, float] = (AttitudeLimits.thrust_min, AttitudeLimits.thrust_max)
    """The attitude helper's thrust range, in multiples of hover ``m g``."""

    @field_validator("thrust_limits")
    @classmethod
    def _thrust_limits(cls, v: tuple[float, float]) -> tuple[float, float]:
        return check_thrust_limits(v)

    @property
    def limits(self) -> AttitudeLimits:
        return AttitudeLimits(self.tilt_limit_deg, *self.thrust_limits)


def limited(f: np.ndarray, mass: float, limits: AttitudeLimits, g: float = GRAVITY) -> np.ndarray:
    """Whether the limits change the demanded force ``f`` (n, 3) (module docstring)."""
    hover = mass * g
    t = math.radians(limits.max_tilt_deg)
    fz_min = limits.thrust_min * hover * math.cos(t)
    norm = np.linalg.norm(f, axis=1)
    return (
        (f[:, 2] < fz_min)
        | (np.hypot(f[:, 0], f[:, 1]) > f[:, 2] * math.tan(t))
        | (norm < limits.thrust_min * hover)
        | (norm > limits.thrust_max * hover)
    )


def thrust_attitude(
    u: np.ndarray,
    acc: np.ndarray,
    mass: float,
    limits: AttitudeLimits = AttitudeLimits(),
    yaw: np.ndarray | float = 0.0,
    g: float = GRAVITY,
) -> tuple[np.ndarray, np.ndarray]:
    """Collective thrust (n,) in newtons and quaternions ``[x, y, z, w]`` (n, 4), limited."""
    f = demanded_force(absolute_input(u, acc, mass, g), mass, g)
    hover = mass * g
    tan_max = math.tan(math.radians(limits.max_tilt_deg))
    fz = np.maximum(
        f[:, 2], limits.thrust_min * hover * math.cos(math.radians(limits.max_tilt_deg))
    )
    fh = np.sqrt(f[:, 0] * f[:, 0] + f[:, 1] * f[:, 1])
    cap = fz * tan_max
    s = np.where(fh > cap, cap / np.where(fh > 0, fh, 1.0), 1.0)
    fx, fy = f[:, 0] * s, f[:, 1] * s
    norm = np.sqrt(fx * fx + fy * fy + fz * fz)
    thrust = np.clip(norm, limits.thrust_min * hover, limits.thrust_max * hover)
    zx, zy, zz = fx / norm, fy / norm, fz / norm
    psi = np.broadcast_to(np.asarray(yaw, dtype=float), zz.shape)
    cy, sy = np.cos(psi), np.sin(psi)
    nx, ny = cy * zx + sy * zy, -sy * zx + cy * zy
    k = 1.0 / np.sqrt(2.0 * (1.0 + zz))
    a, b, c = -ny * k, nx * k, (1.0 + zz) * k
    ch, sh = np.cos(0.5 * psi), np.sin(0.5 * psi)
    q = np.column_stack([ch * a - sh * b, ch * b + sh * a, sh * c, ch * c])
    return thrust, q


def quat_tilt_rad(q: np.ndarray) -> np.ndarray:
    """Angle (n,) between body z of ``q`` ([x, y, z, w]) and world z: ``acos(1 - 2(x^2 + y^2))``."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    return np.arccos(np.clip(1.0 - 2.0 * (q[:, 0] ** 2 + q[:, 1] ** 2), -1.0, 1.0))


def c_function(prefix: str, real: str, float_math: bool) -> str:
    """The C helper ``PREFIX_attitude(u, acc_ref, yaw, &thrust, q)`` (body of the .c file).

    An input that is not finite, a ``u`` or ``acc_ref`` entry beyond ``+/- PREFIX_Y_MAX`` (the
    step's bound: far beyond any real command, far inside float range), or a result that is
    not finite gives hover: thrust ``m g``, the level attitude at the commanded yaw (yaw 0
    when it is not finite)."""
    m = prefix.upper()
    f = "f" if float_math else ""
    zero, one, half, two = (
        ("0.0f", "1.0f", "0.5f", "2.0f") if float_math else ("0.0", "1.0", "0.5", "2.0")
    )
    return f"""/* Hover: thrust m g, level at the yaw (0 when the yaw is not finite). */
static int {prefix}_within({real} x)
{{
    return x >= -{m}_Y_MAX && x <= {m}_Y_MAX; /* a NaN fails both */
}}

static void {prefix}_hover({real} yaw, {real} *thrust, {real} q[4])
{{
    const {real} psi = isfinite(yaw) ? yaw : {zero};
    *thrust = {m}_MASS * {m}_GRAVITY;
    q[0] = {zero};
    q[1] = {zero};
    q[2] = sin{f}({half} * psi);
    q[3] = cos{f}({half} * psi);
}}

void {prefix}_attitude(const {real} u[{m}_NU], const {real} acc_ref[3], {real} yaw,
                {real} *thrust, {real} q[4])
{{
    const {real} hover = {m}_MASS * {m}_GRAVITY;
    {real} fx, fy, fz, fh, cap, norm, th, zx, zy, zz, nx, ny, k, a, b, c, ch, sh, cy, sy;
    {real} qq[4];
    const {real} fz_min = {m}_THRUST_MIN * hover * cos{f}({m}_MAX_TILT);
    if (!({prefix}_within(u[0]) && {prefix}_within(u[1]) && {prefix}_within(u[2])
          && {prefix}_within(acc_ref[0]) && {prefix}_within(acc_ref[1])
          && {prefix}_within(acc_ref[2]) && isfinite(yaw))) {{
        {prefix}_hover(yaw, thrust, q);
        return;
    }}
    /* f = m (a_ref + a_u + g e3), a_u = [-g u0, g u1, u2 / m] */
    fx = {m}_MASS * (acc_ref[0] - {m}_GRAVITY * u[0]);
    fy = {m}_MASS * (acc_ref[1] + {m}_GRAVITY * u[1]);
    fz = {m}_MASS * (acc_ref[2] + {m}_GRAVITY) + u[2];
    if (fz < fz_min) fz = fz_min; /* the rotors only push up */
    fh = sqrt{f}(fx * fx + fy * fy);
    cap = fz * tan{f}({m}_MAX_TILT);
    if (fh > cap) {{ /* tilt limit: scale the horizontal force */
        fx *= cap / fh;
        fy *= cap / fh;
    }}
    norm = sqrt{f}(fx * fx + fy * fy + fz * fz);
    th = norm < {m}_THRUST_MIN * hover ? {m}_THRUST_MIN * hover
       : norm > {m}_THRUST_MAX * hover ? {m}_THRUST_MAX * hover : norm;
    zx = fx / norm;
    zy = fy / norm;
    zz = fz / norm;
    /* q = q_z(yaw) * (minimal rotation e3 -> Rz(-yaw) z_b) */
    cy = cos{f}(yaw);
    sy = sin{f}(yaw);
    nx = cy * zx + sy * zy;
    ny = -sy * zx + cy * zy;
    k = {one} / sqrt{f}({two} * ({one} + zz));
    a = -ny * k;
    b = nx * k;
    c = ({one} + zz) * k;
    ch = cos{f}({half} * yaw);
    sh = sin{f}({half} * yaw);
    qq[0] = ch * a - sh * b;
    qq[1] = ch * b + sh * a;
    qq[2] = sh * c;
    qq[3] = ch * c;
    if (!(isfinite(th) && isfinite(qq[0]) && isfinite(qq[1]) && isfinite(qq[2])
          && isfinite(qq[3]))) {{ /* overflowed */
        {prefix}_hover(yaw, thrust, q);
        return;
    }}
    *thrust = th;
    memcpy(q, qq, sizeof qq);
}}
"""


def py_function(limits: AttitudeLimits) -> str:
    """The stdlib Python ``attitude(u, acc_ref, yaw=0.0)`` of the exported module."""
    return f'''
MAX_TILT = {math.radians(limits.max_tilt_deg)!r}  # rad ({limits.max_tilt_deg:g} deg)
THRUST_MIN = {limits.thrust_min!r}  # x MASS * GRAVITY
THRUST_MAX = {limits.thrust_max!r}  # x MASS * GRAVITY


def _hover(yaw):
    """Hover: thrust MASS * GRAVITY, level at the yaw (0 when the yaw is not finite)."""
    try:
        psi = float(yaw)
    except (TypeError, ValueError, OverflowError):
        psi = 0.0
    if not math.isfinite(psi):
        psi = 0.0
    return MASS * GRAVITY, [0.0, 0.0, math.sin(0.5 * psi), math.cos(0.5 * psi)]


def attitude(u, acc_ref, yaw=0.0):
    """``(thrust [N], q [x, y, z, w])`` from ``u``, the reference acceleration and the yaw.

    f = m (a_ref + [-g u0, g u1, u2 / m] + g e3), f_z >= THRUST_MIN m g cos(MAX_TILT),
    |f_xy| <= f_z tan(MAX_TILT), thrust = |f| clamped to [THRUST_MIN, THRUST_MAX] m g,
    body z = f / |f|, q = q_z(yaw) * (minimal rotation e3 -> Rz(-yaw) body z). A u or
    acc_ref entry that is not a finite number within +/- Y_MAX, a yaw that is not finite, or a
    result that is not finite gives _hover(yaw).
    """
    try:
        u0, u1, u2 = float(u[0]), float(u[1]), float(u[2])
        a0, a1, a2 = float(acc_ref[0]), float(acc_ref[1]), float(acc_ref[2])
        yaw = float(yaw)
    except (TypeError, ValueError, OverflowError):
        return _hover(yaw)
    if not (all(-Y_MAX <= v <= Y_MAX for v in (u0, u1, u2, a0, a1, a2)) and math.isfinite(yaw)):
        return _hover(yaw)
    hover = MASS * GRAVITY
    fx = MASS * (a0 - GRAVITY * u0)
    fy = MASS * (a1 + GRAVITY * u1)
    fz = MASS * (a2 + GRAVITY) + u2
    fz = max(fz, THRUST_MIN * hover * math.cos(MAX_TILT))
    fh = math.sqrt(fx * fx + fy * fy)
    cap = fz * math.tan(MAX_TILT)
    if fh > cap:
        fx *= cap / fh
        fy *= cap / fh
    norm = math.sqrt(fx * fx + fy * fy + fz * fz)
    thrust = min(max(norm, THRUST_MIN * hover), THRUST_MAX * hover)
    zx, zy, zz = fx / norm, fy / norm, fz / norm
    cy, sy = math.cos(yaw), math.sin(yaw)
    nx, ny = cy * zx + sy * zy, -sy * zx + cy * zy
    k = 1.0 / math.sqrt(2.0 * (1.0 + zz))
    a, b, c = -ny * k, nx * k, (1.0 + zz) * k
    ch, sh = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    q = [ch * a - sh * b, ch * b + sh * a, sh * c, ch * c]
    if not all(map(math.isfinite, (thrust, *q))):  # overflowed
        return _hover(yaw)
    return thrust, q
'''
