"""Position controllers behind one small interface, in the paper's input convention.

A :class:`PositionController` is called every ``dt`` with the state estimate ``y = [p, v]`` (the VIO
estimate on the vehicle, never the truth, unless a test asks for truth feedback), the
estimated attitude and the reference, and returns the ABSOLUTE input
``[pitch, roll, thrust]`` in the paper's signs (``vx' = -g pitch``, ``vy' = +g roll``,
thrust in newtons). The vehicle interface (:func:`qsls.pipeline.sim.vehicle.paper_to_ctatt`)
converts it once for RotorPy's ``cmd_ctatt``.

Hover input ``[0, 0, m g]``; the reference's feedforward maps its acceleration ``a_r``
through the paper's ``B``: ``u_ff = [-a_x / g, a_y / g, m a_z]``.

- :class:`SE3Controller`: RotorPy's ``SE3Control`` (Lee et al. 2010; the geometric
  controller that records the training flights, as the paper's SO(3) controller did). Its
  commanded attitude and thrust are read back as pitch and roll
  (:func:`~qsls.pipeline.sim.vehicle.ctatt_to_paper`, yaw 0).
- :class:`PDController`: ``u = hover + u_ff + K (y - r)`` with ``K`` from
  :func:`qsls.pipeline.control.pdgain.pd_gain`.
- :class:`LinearController`: a synthesized controller from
  :func:`qsls.pipeline.control.artifacts.load_runtime` (``.dt``, ``.reset()``, ``.step(y - r)`` ->
  deviation from hover + feedforward).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Protocol

import numpy as np

from qsls.pipeline.control.artifacts import (
    CERTIFICATE_FILE,
    CONTROLLER_FILE,
    Certificate,
    load_runtime,
)
from qsls.pipeline.control.gate import gated_deviation
from qsls.pipeline.control.pdgain import PDGains, pd_gain
from qsls.pipeline.control.realize import StaticGainController
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.plant import GRAVITY, NX, PAPER_DT_S, Plant, feedforward_input
from qsls.pipeline.core.references import RefSample
from qsls.pipeline.export.cbuild import c_runtime
from qsls.pipeline.sim.options import ControllerOptions
from qsls.pipeline.sim.vehicle import ctatt_to_paper, quad_params

SE3_HZ = 100.0


class PositionController(Protocol):
    """What the closed loop calls every ``dt``."""

    name: str
    dt: float

    def reset(self) -> None: ...

    def command(self, t: float, y: np.ndarray, q: np.ndarray, ref: RefSample) -> np.ndarray:
        """Absolute ``[pitch, roll, thrust]`` (paper signs) from estimate ``y``, attitude ``q``."""
        ...


def hover_input(mass: float, g: float = GRAVITY) -> np.ndarray:
    return np.array([0.0, 0.0, mass * g])


def feedforward(ref: RefSample, mass: float, g: float = GRAVITY) -> np.ndarray:
    """``uff``: the model's feedforward the flight computed for the tick (``ref.uff``,
    :meth:`qsls.pipeline.core.references.Reference.feedforward`), else the reference
    acceleration through the paper's ``B``, ``[-a_x / g, a_y / g, m a_z]``
    (:func:`qsls.pipeline.core.plant.feedforward_input`)."""
    if ref.uff is not None:
        return ref.uff
    return feedforward_input(ref.a, mass, g)


class SE3Controller:
    """RotorPy's ``SE3Control`` read back as the paper's ``[pitch, roll, thrust]``.

    ``backend="rotorpy"`` calls ``SE3Control.update`` itself; ``"fast"`` (default) evaluates
    the same law in scalar arithmetic (its thrust and attitude only, which is all that
    ``cmd_ctatt`` uses; checked against ``SE3Control.update`` in the tests)::

        F = m (-kp (p - p_r) - kd (v - v_r) + a_r + g e3),  thrust = F . R(q) e3,
        b3 = F / |F|,  b2 = b3 x c1 / |b3 x c1| (c1 = e1: yaw 0),  b1 = b2 x b3.
    """

    name = "se3"

    def __init__(
        self,
        params: dict[str, Any],
        dt: float,
        kp: Any = None,
        kd: Any = None,
        backend: str = "fast",
    ) -> None:
        from rotorpy.controllers.quadrotor_control import SE3Control

        self.dt = float(dt)
        self.backend = backend
        self._se3 = SE3Control(params)
        if kp is not None:
            self._se3.kp_pos = np.asarray(kp, dtype=float)
        if kd is not None:
            self._se3.kd_pos = np.asarray(kd, dtype=float)
        self._kp = [float(v) for v in self._se3.kp_pos]
        self._kd = [float(v) for v in self._se3.kd_pos]
        self._m = float(self._se3.mass)
        self._g = float(self._se3.g)
        self._zero3 = np.zeros(3)

    def reset(self) -> None:
        pass

    def command(self, t: float, y: np.ndarray, q: np.ndarray, ref: RefSample) -> np.ndarray:
        if self.backend == "rotorpy":
            return self._command_rotorpy(t, y, q, ref)
        yy, pr, vr, ar = y.tolist(), ref.p.tolist(), ref.v.tolist(), ref.a.tolist()
        kp, kd, m = self._kp, self._kd, self._m
        f = [m * (-kp[i] * (yy[i] - pr[i]) - kd[i] * (yy[3 + i] - vr[i]) + ar[i]) for i in range(3)]
        f[2] += m * self._g
        qx, qy, qz, qw = q.tolist()
        n2 = qx * qx + qy * qy + qz * qz + qw * qw
        # R e3 (q normalized as scipy does)
        b3x = 2 * (qx * qz + qy * qw) / n2
        b3y = 2 * (qy * qz - qx * qw) / n2
        b3z = 1 - 2 * (qx * qx + qy * qy) / n2
        thrust = f[0] * b3x + f[1] * b3y + f[2] * b3z
        nf = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]) ** 0.5
        dx, dy, dz = f[0] / nf, f[1] / nf, f[2] / nf
        # b2 = b3 x e1 / |.| = (0, dz, -dy) / |.|, b1 = b2 x b3: R_des[2, 0] = b1_z, R_des[2, 1] = b2_z
        nb = (dz * dz + dy * dy) ** 0.5
        b2y, b2z = dz / nb, -dy / nb
        b1z = -b2y * dx  # b1 = b2 x b3, z component: b2x*b3y - b2y*b3x with b2x = 0
        theta = np.arcsin(min(1.0, max(-1.0, -b1z)))
        phi = np.arctan2(b2z, dz)
        return np.array([-theta, -phi, thrust])

    def _command_rotorpy(
        self, t: float, y: np.ndarray, q: np.ndarray, ref: RefSample
    ) -> np.ndarray:
        state = {"x": y[:3], "v": y[3:6], "q": q, "w": self._zero3}
        flat = {
            "x": ref.p,
            "x_dot": ref.v,
            "x_ddot": ref.a,
            "x_dddot": self._zero3,
            "x_ddddot": self._zero3,
            "yaw": 0.0,
            "yaw_dot": 0.0,
        }
        out = self._se3.update(t, state, flat)
        return ctatt_to_paper(out["cmd_thrust"], out["cmd_q"])


class PDController:
    """``u = [0, 0, m g] + u_ff + K (y - r)`` (qsls.pipeline.control.pdgain)."""

    name = "pd"

    def __init__(self, gains: PDGains, mass: float, dt: float) -> None:
        self.dt = float(dt)
        self.mass = float(mass)
        self.K = pd_gain(gains, mass)

    def reset(self) -> None:
        pass

    def command(self, t: float, y: np.ndarray, q: np.ndarray, ref: RefSample) -> np.ndarray:
        u = self.K @ (y - ref.state)
        return hover_input(self.mass) + feedforward(ref, self.mass) + u


class LinearController:
    """A synthesized controller: ``u = hover + u_ff + K.step(y - r)``, ``K`` from realize."""

    def __init__(
        self, runtime: Any, mass: float, name: str, dt: float | None = None,
        gate: float | None = None, plant: Plant | None = None,
    ) -> None:  # fmt: skip
        self.runtime = runtime
        self.mass = float(mass)
        self.name = name
        self.dt = float(dt if dt is not None else runtime.dt)
        self.gate = gate
        """Velocity gate ``V``: the velocity deviation read is clipped to ``[-V, V]``."""
        self.plant: Plant = plant or plant_of(runtime)
        """The plant it was synthesized on: its feedforward is that plant's inverse."""

    def reset(self) -> None:
        self.runtime.reset()

    def command(self, t: float, y: np.ndarray, q: np.ndarray, ref: RefSample) -> np.ndarray:
        dev = gated_deviation(np.asarray(y - ref.state, dtype=float), self.gate)
        u = np.asarray(self.runtime.step(dev), dtype=float)
        return hover_input(self.mass) + feedforward(ref, self.mass) + u.reshape(3)


def plant_of(runtime: Any) -> Plant:
    """The plant a runtime's filter bank was synthesized on: its state is the attitude
    plant's when wider than the physical ``NX`` (a static gain: the hover plant)."""
    nx = getattr(getattr(runtime, "bank", None), "nx", NX)
    return "attitude" if nx > NX else "hover"


def controller_folder(spec: str | Path) -> Path:
    """The folder of a synthesized controller given as a folder or its ``controller.npz``."""
    path = Path(spec)
    if path.is_file() and path.suffix == ".npz":
        path = path.parent
    if not path.is_dir():
        raise InputError(
            f"controller '{spec}': expected 'se3', 'pd' or a synthesized controller folder "
            f"(one holding {CONTROLLER_FILE}, written by qsls synth)"
        )
    return path


def make_controller(options: ControllerOptions, mass: float) -> PositionController:
    """Build the controller named by ``options.kind``."""
    kind = options.kind
    rate_dt = None if options.rate_hz is None else 1.0 / options.rate_hz
    if kind == "se3":
        params = quad_params()
        params["mass"] = float(mass)
        return SE3Controller(
            params, rate_dt or 1.0 / SE3_HZ, options.se3_kp, options.se3_kd, options.se3_backend
        )
    if kind == "pd":
        return PDController(options.pd, mass, rate_dt or PAPER_DT_S)
    folder = controller_folder(kind)

    runtime: Any = load_runtime(folder)
    plant = plant_of(runtime)
    if options.backend == "c" and not isinstance(runtime, StaticGainController):
        runtime = c_runtime(folder)  # the code 'qsls export' writes, compiled, through ctypes
    name = str(getattr(runtime, "name", None) or folder.name)
    if rate_dt is not None and abs(rate_dt - runtime.dt) > 1e-9:
        raise InputError(
            f"controller {folder}: synthesized for dt = {runtime.dt} s, "
            f"cannot run at rate_hz = {options.rate_hz}"
        )

    gate = Certificate.load(folder).gate if (folder / CERTIFICATE_FILE).is_file() else None
    return LinearController(runtime, mass, name, gate=gate, plant=plant)
