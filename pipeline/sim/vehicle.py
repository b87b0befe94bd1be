"""The vehicle: RotorPy's ``Multirotor`` with the ``cmd_ctatt`` abstraction, a fast integrator.

**Parameters** (:data:`QUAD_256G`): a small quadrotor like the paper's (Section V-B: "a
0.16 m diameter, 256 g quadrotor" built on a Qualcomm Snapdragon Flight). Where they come
from:

- ``mass`` 0.256 kg: the paper. Arm length ``d`` = 0.08 m: half the 0.16 m diameter.
- Inertia: RotorPy's AscTec Hummingbird (``hummingbird_params.py``: 0.5 kg, d = 0.17 m,
  ``Ixx`` 3.65e-3) scaled by ``m d^2`` (a geometrically similar frame):
  ``Ixx = Iyy = 4.14e-4``, ``Izz = 7.97e-4`` kg m^2.
- Rotors: ``rotor_speed_max`` 3000 rad/s with a thrust-to-weight ratio of 2.2 gives
  ``k_eta = 2.2 m g / (4 * 3000^2) = 1.535e-7`` N/(rad/s)^2 (hover at ~2020 rad/s);
  ``k_m`` keeps the Hummingbird's torque-to-thrust ratio (0.0244 m). Motor time constant
  ``tau_m`` 0.02 s, between the Hummingbird (0.005 s) and the Crazyflie (0.072 s).
- Aerodynamics: parasitic drag scaled from the Hummingbird by frontal area (``d^2``); rotor
  drag ``k_d``, ``k_z`` chosen so the linear drag per unit mass at hover matches RotorPy's
  Crazyflie (``4 k_d omega_hover / m`` = 0.245 1/s; ``k_z / k_d`` as the Crazyflie's);
  translational lift ``k_h`` with the Hummingbird's ratio to the hover thrust.
- Attitude loop (``cmd_ctatt``): the Hummingbird's gains ``kp_att`` 544, ``kd_att`` 46.64
  (an angular-acceleration PD: natural frequency 23 rad/s, damping 1), run at the physics
  rate as RotorPy does (its attitude loop is evaluated once per ``Multirotor.step``).

**Signs** (docs/model.md#signs-paper-b-against-a-z-up-body-frame): the paper's ``B`` has ``vx' = -g pitch``, ``vy' = +g roll``; in
RotorPy's z-up body frame a right-handed rotation ``theta`` about body y gives
``x'' = +g theta`` and ``phi`` about x gives ``y'' = -g phi``. The conversion happens once,
in :func:`paper_to_ctatt`: ``theta = -pitch``, ``phi = -roll``, attitude
``R = R_z(0) R_y(theta) R_x(phi)``, collective thrust unchanged.

**Conditions the controller is not told** (docs/calibration.md#conditions-as-a-stated-family):
``thrust_constant`` scales the rotors' ``k_eta`` in :meth:`Vehicle.derivative` while
:meth:`Vehicle.motor_command` allocates with the nominal one (thrust = ``thrust_constant``
times the command); a battery's sag scales the commanded rotor speeds per step
(:meth:`Vehicle.step`'s ``speed_scale``); the wind is the state's ``s[13:16]``, as RotorPy
carries it (:mod:`qsls.pipeline.sim.wind`).

**Integration.** RotorPy's ``Multirotor.step`` holds the motor command over a step and calls
``scipy.integrate.solve_ivp`` (RK45) every step: ~3.6 ms per step here. :class:`Vehicle`
keeps exactly that model (same state vector, same equations: :meth:`Vehicle.derivative`
reproduces ``Multirotor._s_dot_fn`` and :meth:`Vehicle.motor_command`
``Multirotor.get_cmd_motor_speeds``, both checked against RotorPy in the tests) but
evaluates it with plain array code and integrates each step with fixed-step classical
Runge-Kutta 4 (``substeps`` per step), renormalizing the quaternion after the step as
RotorPy does. The RK4 stages run on plain floats in the order the whole-array form
(:meth:`Vehicle.step_numpy`) evaluates them, the same bits faster
(docs/performance.md#flights).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from qsls.pipeline.core.errors import ConfigError
from qsls.pipeline.core.plant import GRAVITY
from qsls.pipeline.core.rotations import quat_to_matrix
from qsls.pipeline.sim.options import VehicleOptions

_D = 0.08  # arm length (m)
_S2 = 0.70710678118

QUAD_256G: dict[str, Any] = {
    "mass": 0.256,
    "Ixx": 4.14e-4,
    "Iyy": 4.14e-4,
    "Izz": 7.97e-4,
    "Ixy": 0.0,
    "Iyz": 0.0,
    "Ixz": 0.0,
    "num_rotors": 4,
    "rotor_radius": 0.035,
    "rotor_pos": {
        "r1": _D * np.array([_S2, _S2, 0]),
        "r2": _D * np.array([_S2, -_S2, 0]),
        "r3": _D * np.array([-_S2, -_S2, 0]),
        "r4": _D * np.array([-_S2, _S2, 0]),
    },
    "rotor_directions": np.array([1, -1, 1, -1]),
    "rI": np.array([0, 0, 0]),
    "c_Dx": 1.1e-3,
    "c_Dy": 1.1e-3,
    "c_Dz": 2.2e-3,
    "k_eta": 1.535e-7,
    "k_m": 3.75e-9,
    "k_d": 7.75e-6,
    "k_z": 5.7e-6,
    "k_h": 1.74e-3,
    "k_flap": 0.0,
    "tau_m": 0.02,
    "rotor_speed_min": 0.0,
    "rotor_speed_max": 3000.0,
    "motor_noise_std": 0.0,
    "k_w": 1,
    "k_v": 10,
    "kp_att": 544.0,
    "kd_att": 46.64,
}


def quad_params(options: VehicleOptions | None = None) -> dict[str, Any]:
    """RotorPy's parameter dict for the vehicle (QUAD_256G with the options' mass)."""
    params = dict(QUAD_256G)
    if options is not None:
        params["mass"] = float(options.mass)
    return params


def paper_to_ctatt(u: np.ndarray) -> tuple[float, np.ndarray]:
    """Absolute paper input ``[pitch, roll, thrust]`` -> RotorPy ``(cmd_thrust, cmd_q)``.

    ``theta = -pitch`` about body y, ``phi = -roll`` about body x, yaw 0;
    ``q = q_y(theta) * q_x(phi)`` as ``[x, y, z, w]``.
    """
    th = -0.5 * float(u[0])
    ph = -0.5 * float(u[1])
    ct, st, cp, sp = np.cos(th), np.sin(th), np.cos(ph), np.sin(ph)
    q = np.array([ct * sp, st * cp, -st * sp, ct * cp])
    return float(u[2]), q


def ctatt_to_paper(thrust: float, q: np.ndarray) -> np.ndarray:
    """Inverse of :func:`paper_to_ctatt` (yaw dropped): RotorPy command -> paper input."""
    x, y, z, w = (float(v) for v in q)
    # R = Rz(psi) Ry(theta) Rx(phi): theta = asin(-R[2,0]), phi = atan2(R[2,1], R[2,2])
    r20 = 2.0 * (x * z - w * y)
    r21 = 2.0 * (y * z + w * x)
    r22 = 1.0 - 2.0 * (x * x + y * y)
    theta = np.arcsin(np.clip(-r20, -1.0, 1.0))
    phi = np.arctan2(r21, r22)
    return np.array([-theta, -phi, float(thrust)])


class Vehicle:
    """RotorPy's ``Multirotor`` (``cmd_ctatt``) with a fast fixed-step RK4 integrator.

    State: RotorPy's 20-vector ``s = [x(3), v(3), q(4) xyzw, w(3) body rates, wind(3),
    rotor_speeds(4)]``.
    """

    def __init__(self, options: VehicleOptions | None = None) -> None:
        from rotorpy.vehicles.multirotor import Multirotor

        self.options = options or VehicleOptions()
        o = self.options
        if o.integrator == "solve_ivp" and (o.thrust_constant != 1.0 or o.sag != 0.0):
            raise ConfigError(
                "vehicle.thrust_constant and vehicle.sag fly with vehicle.integrator rk4 "
                "(RotorPy's stock step allocates with its own k_eta)"
            )
        self.params = quad_params(self.options)
        self.multirotor = Multirotor(
            self.params,
            control_abstraction="cmd_ctatt",
            aero=self.options.aero,
            enable_ground=False,
            integrator_kwargs=None
            if self.options.ivp_rtol is None
            else {
                "method": "RK45",
                "rtol": self.options.ivp_rtol,
                "atol": 1e-3 * self.options.ivp_rtol,
            },
        )
        mr = self.multirotor
        self.mass = float(mr.mass)
        self.g = float(mr.g)
        self.inertia = np.asarray(mr.inertia, dtype=float)
        self.inv_inertia = np.asarray(mr.inv_inertia, dtype=float)
        self.geometry = np.asarray(mr.rotor_geometry, dtype=float)  # (4, 3)
        self._geom = [tuple(float(v) for v in row) for row in self.geometry]
        self.k_eta = float(mr.k_eta)
        # the rotors' true thrust constant; the allocation (motor_command) keeps the nominal
        self.k_eta_rotor = self.k_eta * float(self.options.thrust_constant)
        self.k_m = float(mr.k_m)
        self.k_h = float(mr.k_h)
        self.k_flap = float(mr.k_flap)
        self.tau_m = float(mr.tau_m)
        self.drag = np.diag(mr.drag_matrix).astype(float)
        self.rotor_drag = np.diag(mr.rotor_drag_matrix).astype(float)
        self.rotor_dir = np.asarray(mr.rotor_dir, dtype=float)
        self.TM_to_f = np.asarray(mr.TM_to_f, dtype=float)
        self.kp_att = float(mr.kp_att)
        self.kd_att = float(mr.kd_att)
        self.speed_min = float(mr.rotor_speed_min)
        self.speed_max = float(mr.rotor_speed_max)
        self.aero = bool(mr.aero)
        self.max_tilt = np.radians(self.options.max_tilt_deg)
        # plain-float copies for the scalar derivative
        self._rotor_drag = tuple(float(v) for v in self.rotor_drag)
        self._drag = tuple(float(v) for v in self.drag)
        self._yaw_coef = [float(d) * self.k_m for d in self.rotor_dir]
        self._inertia = [tuple(float(v) for v in row) for row in self.inertia]
        self._inv_inertia = [tuple(float(v) for v in row) for row in self.inv_inertia]
        self.hover_speed = float(np.sqrt(self.mass * self.g / (4 * self.k_eta)))
        self._r_des_key = b""
        self._r_des = np.eye(3)

    # ---------------------------------------------------------------- states and commands
    def hover_state(self, position: np.ndarray, velocity: np.ndarray | None = None) -> np.ndarray:
        """Level attitude at ``position`` with the rotors at hover speed."""
        s = np.zeros(20)
        s[0:3] = position
        if velocity is not None:
            s[3:6] = velocity
        s[9] = 1.0
        s[16:20] = self.hover_speed
        return s

    def command(self, u: np.ndarray) -> tuple[float, np.ndarray]:
        """Absolute paper input -> ``(cmd_thrust, cmd_q)``, tilt and thrust clipped."""
        pitch = float(np.clip(u[0], -self.max_tilt, self.max_tilt))
        roll = float(np.clip(u[1], -self.max_tilt, self.max_tilt))
        thrust = float(np.clip(u[2], 0.0, 4 * self.k_eta * self.speed_max**2))
        return paper_to_ctatt(np.array([pitch, roll, thrust]))

    def command_px4(
        self, thrust_sp: float, q_d: np.ndarray, hover_thrust: float
    ) -> tuple[float, np.ndarray]:
        """PX4's attitude setpoint -> ``(cmd_thrust, cmd_q)``: the normalized thrust
        ``thrust_sp`` (clipped to ``[0, 1]``) is ``thrust_sp m g / hover_thrust`` newtons (a
        linear thrust curve, ``THR_MDL_FAC = 0``: ``hover_thrust`` is the throttle that holds
        this vehicle's weight), within the rotors' limit; the attitude ``q_d`` ``[x, y, z, w]``
        (z up) as it is, its tilt already limited by the interface."""
        t = min(max(float(thrust_sp), 0.0), 1.0)
        thrust = min(t * self.mass * self.g / hover_thrust, 4 * self.k_eta * self.speed_max**2)
        return thrust, np.asarray(q_d, dtype=float)

    def motor_command(self, s: np.ndarray, thrust: float, cmd_q: np.ndarray) -> np.ndarray:
        """``Multirotor.get_cmd_motor_speeds`` for ``cmd_ctatt``, clipped as in ``step``."""
        return np.array(self._motor_speeds(s, thrust, cmd_q))

    def _motor_speeds(self, s: np.ndarray, thrust: float, cmd_q: np.ndarray) -> list[float]:
        """:meth:`motor_command` as plain floats. The matrix products stay numpy's (BLAS sums
        in its own order); the elementwise rest, ``clip(sign(f) sqrt(|f| / k_eta))``, is
        cheaper on four floats."""
        r = quat_to_matrix(s[6:10])
        key = cmd_q.tobytes()
        if key != self._r_des_key:  # the command is held over many steps: convert it once
            self._r_des_key, self._r_des = key, quat_to_matrix(cmd_q)
        r_des = self._r_des
        e = (0.5 * (r_des.T @ r - r.T @ r_des)).tolist()
        w = s[10:13]
        w0, w1, w2 = w.tolist()
        i0, i1, i2 = (self.inertia @ w).tolist()
        kp, kd = -self.kp_att, self.kd_att
        pd = np.array([kp * -e[1][2] - kd * w0, kp * e[0][2] - kd * w1, kp * -e[0][1] - kd * w2])
        m0, m1, m2 = (self.inertia @ pd).tolist()
        m0 += w1 * i2 - w2 * i1
        m1 += w2 * i0 - w0 * i2
        m2 += w0 * i1 - w1 * i0
        f = self.TM_to_f @ np.array([thrust, m0, m1, m2])
        k_eta, lo, hi = self.k_eta, self.speed_min, self.speed_max
        out = []
        for fk in f.tolist():
            v = fk / k_eta
            root = math.sqrt(abs(v))
            v = root if v > 0 else (-root if v < 0 else (0.0 if v == 0 else v))  # sign(v) sqrt|v|
            out.append(min(max(v, lo), hi))  # np.clip
        return out

    def derivative(self, s: np.ndarray, cmd_speeds: np.ndarray) -> np.ndarray:
        """``ds/dt`` of ``Multirotor._s_dot_fn`` (RotorPy's equations) for held ``cmd_speeds``.

        Written out in scalar arithmetic, rotor by rotor: on 3- and 4-element arrays numpy's
        per-call overhead costs far more than the math.
        """
        return np.array(self._derivative(s.tolist(), cmd_speeds.tolist()))

    def _derivative(self, s: list[float], cmd: list[float]) -> list[float]:
        vx, vy, vz = s[3], s[4], s[5]
        x, y, z, qw = s[6], s[7], s[8], s[9]
        wx, wy, wz = s[10], s[11], s[12]
        om = s[16:20]
        nq = 1.0 / (x * x + y * y + z * z + qw * qw) ** 0.5
        a, b, c, d = x * nq, y * nq, z * nq, qw * nq
        r00, r01, r02 = 1 - 2 * (b * b + c * c), 2 * (a * b - c * d), 2 * (a * c + b * d)
        r10, r11, r12 = 2 * (a * b + c * d), 1 - 2 * (a * a + c * c), 2 * (b * c - a * d)
        r20, r21, r22 = 2 * (a * c - b * d), 2 * (b * c + a * d), 1 - 2 * (a * a + b * b)
        ux, uy, uz = vx - s[13], vy - s[14], vz - s[15]
        # body airspeed R^T (v - wind)
        bx = r00 * ux + r10 * uy + r20 * uz
        by = r01 * ux + r11 * uy + r21 * uz
        bz = r02 * ux + r12 * uy + r22 * uz
        fbx, fby, fbz, mx, my, mz = self._body_wrench(bx, by, bz, wx, wy, wz, om)
        im = 1.0 / self.mass
        (i00, i01, i02), (i10, i11, i12), (i20, i21, i22) = self._inertia
        iwx = i00 * wx + i01 * wy + i02 * wz
        iwy = i10 * wx + i11 * wy + i12 * wz
        iwz = i20 * wx + i21 * wy + i22 * wz
        tx = mx - (wy * iwz - wz * iwy)
        ty = my - (wz * iwx - wx * iwz)
        tz = mz - (wx * iwy - wy * iwx)
        (j00, j01, j02), (j10, j11, j12), (j20, j21, j22) = self._inv_inertia
        itau = 1.0 / self.tau_m
        return [
            vx,
            vy,
            vz,
            (r00 * fbx + r01 * fby + r02 * fbz) * im,
            (r10 * fbx + r11 * fby + r12 * fbz) * im,
            (r20 * fbx + r21 * fby + r22 * fbz) * im - self.g,
            0.5 * (qw * wx - z * wy + y * wz),
            0.5 * (z * wx + qw * wy - x * wz),
            0.5 * (-y * wx + x * wy + qw * wz),
            0.5 * (-x * wx - y * wy - z * wz),
            j00 * tx + j01 * ty + j02 * tz,
            j10 * tx + j11 * ty + j12 * tz,
            j20 * tx + j21 * ty + j22 * tz,
            0.0,
            0.0,
            0.0,
            (cmd[0] - om[0]) * itau,
            (cmd[1] - om[1]) * itau,
            (cmd[2] - om[2]) * itau,
            (cmd[3] - om[3]) * itau,
        ]

    def _body_wrench(
        self, bx: float, by: float, bz: float, wx: float, wy: float, wz: float, om: list[float]
    ) -> tuple[float, float, float, float, float, float]:
        """The body-frame force and moment of RotorPy's equations at body airspeed ``b`` and
        body rate ``w``: per rotor ``k`` at ``r_k``, thrust ``k_eta o_k^2`` and, with ``aero``,
        the local airspeed ``l = b + w x r_k`` giving the rotor's drag ``-o_k K_d l`` (x, y),
        translational lift ``k_h (l_x^2 + l_y^2)`` and flapping moment ``k_flap o_k (-l_y, l_x)``;
        moments ``r_k x F_k`` plus the yaw drag ``dir_k k_m o_k^2``; then the airframe's drag
        ``-|b| C_d b``."""
        k_eta, k_h, k_flap = self.k_eta_rotor, self.k_h, self.k_flap
        kdx, kdy, kdz = self._rotor_drag
        fbx = fby = fbz = 0.0
        mx = my = mz = 0.0
        mfx = mfy = 0.0
        aero = self.aero
        for k in range(4):
            gx, gy, gz = self._geom[k]
            o = om[k]
            t = k_eta * o * o
            if aero:
                # local airspeed at the hub: airspeed + w x r_k
                lx = bx + (wy * gz - wz * gy)
                ly = by + (wz * gx - wx * gz)
                lz = bz + (wx * gy - wy * gx)
                hx = -o * kdx * lx
                hy = -o * kdy * ly
                fz = t + k_h * (lx * lx + ly * ly) - o * kdz * lz
                if k_flap:
                    mfx -= k_flap * o * ly
                    mfy += k_flap * o * lx
            else:
                hx = hy = 0.0
                fz = t
            fbx += hx
            fby += hy
            fbz += fz
            # r_k x F_k
            mx += gy * fz - gz * hy
            my += gz * hx - gx * fz
            mz += gx * hy - gy * hx + self._yaw_coef[k] * o * o
        if aero:
            speed = (bx * bx + by * by + bz * bz) ** 0.5
            cdx, cdy, cdz = self._drag
            fbx -= speed * cdx * bx
            fby -= speed * cdy * by
            fbz -= speed * cdz * bz
        mx += mfx
        my += mfy
        return fbx, fby, fbz, mx, my, mz

    # ---------------------------------------------------------------- integration
    def step(
        self, s: np.ndarray, thrust: float, cmd_q: np.ndarray, h: float, speed_scale: float = 1.0
    ) -> np.ndarray:
        """One step of length ``h``: motor command held, RK4 (``substeps``), quaternion renormalized.

        ``speed_scale`` multiplies the commanded rotor speeds after their limits (a sagging
        battery: ``sqrt(1 - sag t / duration)``, so the thrust for the same command falls by
        ``sag t / duration``); the wind is the state's ``s[13:16]``, held over the step.

        ``k1 = f(s)``, ``k2 = f(s + dt/2 k1)``, ``k3 = f(s + dt/2 k2)``, ``k4 = f(s + dt k3)``,
        ``s+ = s + dt/6 (k1 + 2 k2 + 2 k3 + k4)`` on plain floats, element by element in the
        order :meth:`step_numpy` evaluates it (the same bits, docs/performance.md#flights): a
        20-element numpy expression costs more in call overhead than in arithmetic.
        """
        if self.options.integrator == "solve_ivp":
            return self.step_rotorpy(s, thrust, cmd_q, h)
        cmd = self._motor_speeds(s, thrust, cmd_q)
        if speed_scale != 1.0:
            cmd = [c * speed_scale for c in cmd]
        n = self.options.substeps
        dt = h / n
        half, sixth = 0.5 * dt, dt / 6.0
        f = self._derivative
        x = s.tolist()
        for _ in range(n):
            k1 = f(x, cmd)
            k2 = f([a + half * b for a, b in zip(x, k1, strict=True)], cmd)
            k3 = f([a + half * b for a, b in zip(x, k2, strict=True)], cmd)
            k4 = f([a + dt * b for a, b in zip(x, k3, strict=True)], cmd)
            x = [
                a + sixth * (b1 + 2.0 * b2 + 2.0 * b3 + b4)
                for a, b1, b2, b3, b4 in zip(x, k1, k2, k3, k4, strict=True)
            ]
        out = np.array(x)
        out[6:10] /= np.sqrt(out[6:10] @ out[6:10])  # numpy's dot: its summation order
        return out

    def step_numpy(
        self, s: np.ndarray, thrust: float, cmd_q: np.ndarray, h: float, speed_scale: float = 1.0
    ) -> np.ndarray:
        """:meth:`step` as whole-array numpy expressions (the code before the plain-float one;
        kept as the reference the tests and ``benchmarks/bench_flights.py`` compare with)."""
        if self.options.integrator == "solve_ivp":
            return self.step_rotorpy(s, thrust, cmd_q, h)
        cmd = self.motor_command(s, thrust, cmd_q)
        if speed_scale != 1.0:
            cmd = cmd * speed_scale
        n = self.options.substeps
        dt = h / n
        f = self.derivative
        for _ in range(n):
            k1 = f(s, cmd)
            k2 = f(s + 0.5 * dt * k1, cmd)
            k3 = f(s + 0.5 * dt * k2, cmd)
            k4 = f(s + dt * k3, cmd)
            s = s + (dt / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        s[6:10] /= np.sqrt(s[6:10] @ s[6:10])
        return s

    def step_rotorpy(self, s: np.ndarray, thrust: float, cmd_q: np.ndarray, h: float) -> np.ndarray:
        """The stock ``Multirotor.step`` (``solve_ivp`` every step), for validation and benchmarks."""
        from rotorpy.vehicles.multirotor import Multirotor

        state = {k: np.array(v, dtype=float) for k, v in Multirotor._unpack_state(s).items()}
        out = self.multirotor.step(state, {"cmd_thrust": thrust, "cmd_q": cmd_q}, h)
        return Multirotor._pack_state(out)

    @staticmethod
    def as_dict(s: np.ndarray) -> dict[str, np.ndarray]:
        """RotorPy's state dict view of ``s``."""
        return {
            "x": s[0:3],
            "v": s[3:6],
            "q": s[6:10],
            "w": s[10:13],
            "wind": s[13:16],
            "rotor_speeds": s[16:20],
        }


__all__ = [
    "GRAVITY",
    "QUAD_256G",
    "Vehicle",
    "VehicleOptions",
    "ctatt_to_paper",
    "paper_to_ctatt",
    "quad_params",
]
