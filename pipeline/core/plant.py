"""The quadrotor's linear model around hover (paper, Linear Quadrotor Model).

State ``x = [px, py, pz, vx, vy, vz]`` (world, z up), input ``u = [pitch, roll, thrust]``
as deviations from hover ``[0, 0, m g]``. Continuous time::

    x' = Ac x + Bc u,   Ac = [[0, I], [0, 0]],
    Bc velocity rows: vx' = -g pitch,  vy' = +g roll,  vz' = thrust / m

(the paper's signs; the vehicle interface converts to a right-handed z-up body frame).
Discretized by zero-order hold at ``dt``: ``x[k+1] = A x[k] + B u[k] + H w[k]``, ``C = I``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Literal

import numpy as np

GRAVITY = 9.81
PAPER_MASS_KG = 0.256
PAPER_DT_S = 0.1
NX, NU, NY = 6, 3, 6
POSITION = (0, 1, 2)
VELOCITY = (3, 4, 5)
GROUPS = {"position": POSITION, "velocity": VELOCITY}
"""The state's channel groups: the premise fits their dense errors apart (docs/guarantee.md,
Channel groups), the velocity gate clips the second."""


def measured_channels(measure: str) -> tuple[int, ...]:
    """Error channels the controller reads: all six (``full``), or the three positions."""
    return POSITION + VELOCITY if measure == "full" else POSITION


def continuous_model(
    mass: float = PAPER_MASS_KG, g: float = GRAVITY
) -> tuple[np.ndarray, np.ndarray]:
    """``(Ac, Bc)`` of the paper's hover linearization."""
    if mass <= 0:
        raise ValueError(f"mass must be positive, got {mass}")
    ac = np.zeros((NX, NX))
    ac[0:3, 3:6] = np.eye(3)
    bc = np.zeros((NX, NU))
    bc[3, 0] = -g
    bc[4, 1] = g
    bc[5, 2] = 1.0 / mass
    return ac, bc


def zoh(ac: np.ndarray, bc: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Zero-order-hold discretization: ``expm([[Ac, Bc], [0, 0]] dt) = [[A, B], [0, I]]``."""
    n, m = bc.shape
    big = np.zeros((n + m, n + m))
    big[:n, :n] = ac
    big[:n, n:] = bc
    from scipy.linalg import expm  # here: the plant's constants are read without scipy

    e = expm(big * dt)
    return e[:n, :n], e[:n, n:]


@dataclass(frozen=True)
class LinearModel:
    """Discrete-time ``(A, B, C, H)`` at step ``dt`` for a vehicle of ``mass``."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    H: np.ndarray
    dt: float
    mass: float

    @property
    def nx(self) -> int:
        return self.A.shape[0]

    @property
    def nu(self) -> int:
        return self.B.shape[1]

    @property
    def ny(self) -> int:
        return self.C.shape[0]

    @property
    def bias_dirs(self) -> np.ndarray:
        """``D_w = H^+ D`` (``(nx, 3)``): the disturbance a constant acceleration bias ``beta``
        (m/s^2, one per axis) puts on one step, in the model's disturbance coordinates
        (docs/guarantee.md, The bias term). A constant acceleration held over ``dt`` moves the
        physical states by ``D beta`` with ``D = [dt^2/2 I; dt I]`` (the zero-order hold of the
        double integrator); the attitude plant's loop states do not see it (they follow the
        commands only)."""
        d = np.zeros((self.nx, 3))
        d[:3] = 0.5 * self.dt**2 * np.eye(3)
        d[3:NX] = self.dt * np.eye(3)
        return np.linalg.pinv(np.asarray(self.H, float)) @ d


@lru_cache(maxsize=64)
def _discrete(dt: float, mass: float, g: float) -> tuple[np.ndarray, np.ndarray]:
    """``(A, B)`` at ``dt`` (one ``expm`` per distinct model: a sweep builds thousands)."""
    return zoh(*continuous_model(mass, g), dt)


def quadrotor_model(
    dt: float = PAPER_DT_S,
    mass: float = PAPER_MASS_KG,
    H: np.ndarray | None = None,
    g: float = GRAVITY,
) -> LinearModel:
    """The paper's discrete model; ``H`` defaults to ``I`` (``||H|| = 1``)."""
    if dt <= 0:
        raise ValueError(f"dt must be positive, got {dt}")
    a, b = (m.copy() for m in _discrete(float(dt), float(mass), float(g)))
    h = np.eye(NX) if H is None else np.asarray(H, dtype=float)
    return LinearModel(A=a, B=b, C=np.eye(NY, NX), H=h, dt=float(dt), mass=float(mass))


# --------------------------------------------------------------------------- the attitude plant
Plant = Literal["hover", "attitude"]
"""``hover``: the paper's 6-state model (the attitude follows the command at once);
``attitude``: the same with the vehicle's attitude loop and rotor lag as states (docs/model.md,
The attitude plant)."""
ATTITUDE_KP = 544.0
"""The attitude loop's proportional gain (RotorPy's Hummingbird ``kp_att``, 1/s^2)."""
ATTITUDE_KD = 46.64
"""Its derivative gain (``kd_att``, 1/s): critically damped at sqrt(544) = 23.3 rad/s."""
THRUST_TAU_S = 0.02
"""The rotors' time constant (``tau_m``): collective thrust follows its command with this lag."""
NA = 5
"""Extra states of the attitude plant: pitch, pitch rate, roll, roll rate, thrust."""


def attitude_continuous(
    mass: float = PAPER_MASS_KG,
    g: float = GRAVITY,
    kp: float = ATTITUDE_KP,
    kd: float = ATTITUDE_KD,
    tau: float = THRUST_TAU_S,
) -> tuple[np.ndarray, np.ndarray]:
    """``(Ac, Bc)`` of the hover model with the attitude loop and the rotor lag as states,
    ``z = [x, theta_p, theta_p', theta_r, theta_r', f]`` (11), the input ``u`` the commanded
    pitch, roll and thrust (deviations, paper signs)::

        vx' = -g theta_p,   vy' = g theta_r,   vz' = f / m,
        theta'' = kp (u_att - theta) - kd theta',   f' = (u_f - f) / tau.

    With ``kp, kd, tau -> fast`` it is the hover model."""
    ac6, _ = continuous_model(mass, g)
    n = NX + NA
    ac = np.zeros((n, n))
    bc = np.zeros((n, NU))
    ac[:NX, :NX] = ac6
    ac[3, 6] = -g
    ac[4, 8] = g
    ac[5, 10] = 1.0 / mass
    for i, j in ((6, 0), (8, 1)):
        ac[i, i + 1] = 1.0
        ac[i + 1, i] = -kp
        ac[i + 1, i + 1] = -kd
        bc[i + 1, j] = kp
    ac[10, 10] = -1.0 / tau
    bc[10, 2] = 1.0 / tau
    return ac, bc


def plant_model(
    plant: Plant = "hover",
    dt: float = PAPER_DT_S,
    mass: float = PAPER_MASS_KG,
    H: np.ndarray | None = None,
    g: float = GRAVITY,
) -> LinearModel:
    """The discrete model of ``plant``. The attitude plant's extra states are the model's own
    response to the inputs (:func:`qsls.pipeline.errormodel.disturbance.input_states`), which
    the controller computes from its commands: ``C = I``, and the premise puts no error on
    them (only the first ``NY`` channels are measured). ``H`` (6 x 6) acts on the physical states."""
    if plant == "hover":
        return quadrotor_model(dt, mass, H, g)
    if dt <= 0:
        raise ValueError(f"dt must be positive, got {dt}")
    a, b = zoh(*attitude_continuous(float(mass), float(g)), float(dt))
    n = NX + NA
    # the attitude rates in units of the loop's natural frequency (theta' / sqrt(kp)): the
    # same plant, its matrices of one scale (the rates' rows were 20x the rest, and the
    # solver's tolerance grew with them)
    s = np.ones(n)
    s[[7, 9]] = 1.0 / np.sqrt(ATTITUDE_KP)
    a = (s[:, None] * a) / s[None, :]
    b = s[:, None] * b
    h = np.zeros((n, n))
    h[:NX, :NX] = np.eye(NX) if H is None else np.asarray(H, dtype=float)
    return LinearModel(A=a, B=b, C=np.eye(n), H=h, dt=float(dt), mass=float(mass))


def feedforward_input(acc: np.ndarray, mass: float, g: float = GRAVITY) -> np.ndarray:
    """``u_ff = [-a_x / g, a_y / g, m a_z]``: the reference acceleration ``acc`` ((3,) or
    (n, 3)) through the paper's ``B`` (its inverse on the velocity rows)."""
    a = np.asarray(acc, dtype=float)
    return np.stack([-a[..., 0] / g, a[..., 1] / g, mass * a[..., 2]], axis=-1)


def feedforward_acceleration(uff: np.ndarray, mass: float, g: float = GRAVITY) -> np.ndarray:
    """The acceleration ``uff`` stands for: the inverse of :func:`feedforward_input`."""
    u = np.asarray(uff, dtype=float)
    return np.stack([-u[..., 0] * g, u[..., 1] * g, u[..., 2] / mass], axis=-1)


def model_feedforward(
    dv: np.ndarray,
    da: np.ndarray,
    dj: np.ndarray,
    dt: float,
    mass: float,
    plant: Plant = "hover",
    g: float = GRAVITY,
) -> np.ndarray:
    """The feedforward ``uff_k`` under which the model follows the reference over the step
    ``[t_k, t_k + dt)`` (docs/guarantee.md, Disturbance in deviation coordinates), ``(n, 3)``,
    from the reference's changes over the step in velocity ``dv``, acceleration ``da`` and
    jerk ``dj`` (each ``(n, 3)``).

    It is the step mean of the plant's continuous-time inverse. Hover plant: the mean
    acceleration ``dv / dt``, with which ``v_{k+1} = v_k + dt a`` holds exactly (and the
    position up to ``dt^3`` times the jerk). Attitude plant: the tilt loop
    ``theta'' = kp (u - theta) - kd theta'`` and the rotor lag ``f' = (u_f - f) / tau`` lead
    by ``u = theta + (kd theta' + theta'') / kp`` and ``u_f = f + tau f'``, whose step means
    are ``(dv + (kd / kp) da + dj / kp) / dt`` (tilt channels, as accelerations) and
    ``(dv + tau da) / dt`` (thrust). Its residual ``r_{k+1} - A r_k - B uff_k`` is 0.003 on
    the default circle at ``dt = 0.1`` against 0.067 for the acceleration sampled at the tick
    (hover plant: 0.0005 against 0.034; ``tests/test_deviation.py``)."""
    dv, da, dj = (np.asarray(z, dtype=float) for z in (dv, da, dj))
    acc = dv / dt
    if plant == "attitude":
        lead = (ATTITUDE_KD / ATTITUDE_KP) * da + dj / ATTITUDE_KP
        acc = np.concatenate([acc[..., :2] + lead[..., :2] / dt,
                              acc[..., 2:] + THRUST_TAU_S * da[..., 2:] / dt], axis=-1)  # fmt: skip
    return feedforward_input(acc, mass, g)
