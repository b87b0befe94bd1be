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

import numpy as np

GRAVITY = 9.81
PAPER_MASS_KG = 0.256
PAPER_DT_S = 0.1
NX, NU, NY = 6, 3, 6


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
