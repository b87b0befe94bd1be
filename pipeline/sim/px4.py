"""The PX4 stand-in's interface: the export's attitude map, the transport of messages, frames.

docs/simulation.md#the-px4-stand-in. Three parts:

- :class:`Px4Interface`: the controller's absolute paper input ``u = [pitch, roll, thrust]``
  goes through the export's exact attitude map
  (:func:`qsls.pipeline.export.attitude.thrust_attitude`, default :class:`AttitudeLimits`,
  yaw 0) to a collective thrust ``F`` (N) and an attitude ``q_d``; PX4 receives ``q_d`` and
  the normalized thrust ``T = hover_estimate F / (m g)`` (``m`` the controller's mass),
  clipped to ``[0, 1]`` as a MAVLink attitude target is; the vehicle then produces
  ``T m_true g / hover_thrust`` (:meth:`qsls.pipeline.sim.vehicle.Vehicle.command_px4`).
- :func:`arrivals`: when each message of a stream arrives, in integer microseconds of
  simulation time: ``ceil((t + latency + jitter) / 1 us)``, in order (first in, first
  out), some never (drops). Rounding up keeps the rule exact: with no latency, jitter or
  drop a message has arrived at a tick (a whole number of µs) exactly when it was captured
  at or before it.
- Frames: the simulator's world is ENU (z up) and its body FLU; PX4's are NED and FRD.
  ``p_ned = [p_e[1], p_e[0], -p_e[2]]`` (its own inverse), body vectors
  ``v_frd = [v_x, -v_y, -v_z]``, and ``q_ned_frd = q(NED<-ENU) q_enu_flu q(FLU<-FRD)``, PX4's
  quaternions in ``[w, x, y, z]`` order (the simulator's in ``[x, y, z, w]``).
"""

from __future__ import annotations

import math

import numpy as np

from qsls.pipeline.core.plant import GRAVITY, feedforward_acceleration
from qsls.pipeline.core.references import RefSample
from qsls.pipeline.core.rotations import quat_mul
from qsls.pipeline.export.attitude import AttitudeLimits, thrust_attitude
from qsls.pipeline.sim.controllers import feedforward, hover_input
from qsls.pipeline.sim.options import Px4Options

US = 1000
"""Nanoseconds per microsecond (PX4's clock unit)."""

_R = 1.0 / math.sqrt(2.0)
Q_NED_ENU = np.array([_R, _R, 0.0, 0.0])
"""``q(NED<-ENU)`` ``[x, y, z, w]``: a half turn about ``(1, 1, 0) / sqrt(2)``."""
Q_FLU_FRD = np.array([1.0, 0.0, 0.0, 0.0])
"""``q(FLU<-FRD)`` ``[x, y, z, w]``: a half turn about x."""


# ------------------------------------------------------------------------------ frames
def enu_to_ned(v: np.ndarray) -> np.ndarray:
    """World vectors ``(n, 3)`` (or ``(3,)``) ENU -> NED: ``[y, x, -z]`` (its own inverse)."""
    v = np.asarray(v, dtype=float)
    return np.stack([v[..., 1], v[..., 0], -v[..., 2]], axis=-1)


ned_to_enu = enu_to_ned


def flu_to_frd(v: np.ndarray) -> np.ndarray:
    """Body vectors FLU -> FRD: ``[x, -y, -z]`` (its own inverse)."""
    v = np.asarray(v, dtype=float)
    return np.stack([v[..., 0], -v[..., 1], -v[..., 2]], axis=-1)


frd_to_flu = flu_to_frd


def quat_enu_flu_to_ned_frd(q: np.ndarray) -> np.ndarray:
    """Attitudes ``(n, 4)`` of a FLU body in ENU ``[x, y, z, w]`` -> of the FRD body in NED,
    PX4's ``[w, x, y, z]``, with ``w >= 0``."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    n = len(q)
    out = quat_mul(quat_mul(np.tile(Q_NED_ENU, (n, 1)), q), np.tile(Q_FLU_FRD, (n, 1)))
    out = np.where(out[:, 3:4] < 0, -out, out)
    return out[:, [3, 0, 1, 2]]


def quat_ned_frd_to_enu_flu(q_wxyz: np.ndarray) -> np.ndarray:
    """Inverse of :func:`quat_enu_flu_to_ned_frd`: PX4's ``[w, x, y, z]`` -> ``[x, y, z, w]``."""
    q = np.atleast_2d(np.asarray(q_wxyz, dtype=float))[:, [1, 2, 3, 0]]
    n = len(q)
    conj = np.array([-1.0, -1.0, -1.0, 1.0])
    out = quat_mul(
        quat_mul(np.tile(Q_NED_ENU * conj, (n, 1)), q), np.tile(Q_FLU_FRD * conj, (n, 1))
    )
    return np.where(out[:, 3:4] < 0, -out, out)


def euler_zyx(q_wxyz: np.ndarray) -> np.ndarray:
    """``(roll, pitch, yaw)`` ``(n, 3)`` of quaternions ``[w, x, y, z]`` (PX4's ``Eulerf``)."""
    w, x, y, z = np.atleast_2d(np.asarray(q_wxyz, dtype=float)).T
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.column_stack([roll, pitch, yaw])


# ------------------------------------------------------------------------------ transport
def arrivals(
    t_ns: np.ndarray,
    latency_s: float,
    jitter_s: float,
    drop: float,
    rng: np.random.Generator,
    *,
    keep_first: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """``(arrival_us (n,) int64, dropped (n,) bool)`` of messages captured at ``t_ns``.

    ``arrival = ceil((t + round((latency + U(0, jitter)) ns)) / 1000)`` µs, then in order
    (``max`` of the arrivals before it, dropped ones aside); a message is dropped with
    probability ``drop``. Both draws are made for every message whatever the options (so the
    same seed gives the same jitter whether or not drops are on). ``keep_first``: the first
    message is the estimator's initial state, there at ``t = 0`` and never dropped."""
    t_ns = np.asarray(t_ns, dtype=np.int64)
    n = len(t_ns)
    jit = rng.uniform(0.0, jitter_s, n)
    dropped = rng.random(n) < drop
    delay_ns = np.round((latency_s + jit) * 1e9).astype(np.int64)
    arr = -(-(t_ns + delay_ns) // US)  # ceil division
    if keep_first and n:
        arr[0] = -(-t_ns[0] // US)
        dropped[0] = False
    kept = arr[~dropped]
    arr[~dropped] = np.maximum.accumulate(kept) if len(kept) else kept
    return arr, dropped


# ------------------------------------------------------------------------------ interface
class Px4Interface:
    """The controller's absolute paper input -> PX4's attitude setpoint (module docstring)."""

    def __init__(
        self, options: Px4Options, mass: float, limits: AttitudeLimits = AttitudeLimits(),
        g: float = GRAVITY,
    ) -> None:  # fmt: skip
        self.options = options
        self.mass = float(mass)
        self.limits = limits
        self.g = float(g)
        self.hover_estimate = float(options.estimate)
        self._hover = hover_input(self.mass, self.g)

    def attitude(self, u: np.ndarray, ref: RefSample) -> tuple[float, np.ndarray]:
        """``(F newtons, q_d [x, y, z, w] ENU/FLU)``: the export's map of ``u``. The map
        takes the deviation ``u - hover - u_ff`` and the reference acceleration, as the
        exported code's ``_attitude`` does."""
        ff = feedforward(ref, self.mass, self.g)
        dev = np.asarray(u, dtype=float) - self._hover - ff
        acc = feedforward_acceleration(ff, self.mass, self.g)  # what the feedforward stands for
        thrust, q = thrust_attitude(dev[None, :], acc[None, :], self.mass, self.limits, 0.0, self.g)
        return float(thrust[0]), q[0]

    def setpoint(self, u: np.ndarray, ref: RefSample) -> tuple[float, np.ndarray]:
        """``(T, q_d [x, y, z, w] ENU/FLU)``: the normalized thrust in ``[0, 1]`` and the
        attitude PX4 receives."""
        thrust, q = self.attitude(u, ref)
        t = self.hover_estimate * thrust / (self.mass * self.g)
        return min(max(t, 0.0), 1.0), q
