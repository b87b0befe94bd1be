"""The runtime-assured controller (docs/monitor.md, The fallback): the certified controller
flies until the onboard premise monitor trips, then a fallback flies to the end.

At every tick ``k`` the monitor (:class:`qsls.pipeline.control.monitor.RuntimeMonitor`, the
rule of docs/monitor.md on the raw deviation ``y_k - r_k``, velocity through the gate ``V``)
reads the tick's measurement **before** a command is chosen, so the tick that trips is
already flown by the fallback: the handover tick is the trip tick. The handover latches (no
hand-back: a trip proves the premise broken on this flight, and nothing the vehicle measures
proves it whole again).

The fallbacks are static, so nothing needs initializing at the handover (bumpless in the
controller's state; the command steps from the certified controller's feedback to the
fallback's on the same deviation, and the attitude loop smooths the step):

- ``pd``: the PD reference ``u = hover + u_ff + K (y_k - r_k)`` on the current estimate and
  the same reference (the synth folder's ``K`` where given);
- ``hold``: the same PD toward a fixed hover point, the estimated position at the trip tick
  with zero velocity and no feedforward (``r_hold = [y_p,trip, 0]``): the vehicle stops
  where it believes it is, and the position deviation is zero at the handover.

Per tick it records the monitor's bits and which controller flew (:attr:`flew`). The monitor
includes the innovation monitor (docs/monitor.md), which models each measurement from the
command flown at the tick before: the assured controller tells it that command (the fallback's
after the handover; the exported C step through ``PREFIX_flown``).

With ``--backend c`` (the exported, compiled controller flying through ctypes:
:func:`qsls.pipeline.export.cbuild.c_runtime`) the exported step's own monitor decides the
handover, as on the vehicle: its step reads the tick's measurement, returns the command and
the monitor's bits together (``PREFIX_step``), so the assured controller steps it every tick,
reads the bits, and from the trip on discards its command for the fallback's. The bits and
the handover tick are those of the Python monitor (the same rule and thresholds, in double).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal, Protocol, runtime_checkable

import numpy as np

from qsls.pipeline.control.artifacts import load_controller_dir
from qsls.pipeline.control.monitor import RuntimeMonitor, innovation_of, monitor_of
from qsls.pipeline.core.references import RefSample
from qsls.pipeline.sim.controllers import PDController, PositionController, feedforward, hover_input

Fallback = Literal["pd", "hold"]
FALLBACKS: tuple[Fallback, ...] = ("pd", "hold")


@runtime_checkable
class ExportedStep(Protocol):
    """An exported controller's runtime (the compiled C through ctypes,
    :class:`qsls.pipeline.export.cbuild.CController`): each ``step`` leaves the monitor's bits
    of its tick in ``flags``."""

    flags: int

    def step(self, y: np.ndarray) -> np.ndarray: ...

    def flown(self, u: np.ndarray) -> None: ...


def exported_runtime(primary: PositionController) -> ExportedStep | None:
    """The exported controller flying as ``primary`` (``backend: c``; inside a PD-height
    wrapper's ``inner``), whose step returns the monitor's bits; None otherwise."""
    inner = getattr(primary, "inner", primary)
    runtime = getattr(inner, "runtime", None)
    return runtime if isinstance(runtime, ExportedStep) else None


class AssuredController:
    """``primary`` until the monitor trips, then ``fallback`` (PD on the reference, or PD
    holding the trip tick's estimated position: module docstring). The monitor is
    ``monitor`` (Python, beside the primary), or with ``monitor=None`` the exported step's
    own (``primary`` flies an exported C controller: :func:`exported_runtime`)."""

    def __init__(
        self, primary: PositionController, fallback: PDController,
        monitor: RuntimeMonitor | None, mode: Fallback = "pd",
    ) -> None:  # fmt: skip
        if mode not in FALLBACKS:
            raise ValueError(f"fallback '{mode}': expected one of {', '.join(FALLBACKS)}")
        self.onboard = exported_runtime(primary) if monitor is None else None
        if monitor is None and self.onboard is None:
            raise ValueError(f"{primary.name}: no monitor, and no exported step to read one from")
        self.primary, self.fallback, self.monitor, self.mode = primary, fallback, monitor, mode
        self.name = f"{primary.name}+assured"
        self.dt = primary.dt
        # the closed loop computes each tick's feedforward for the flying controller's mass and
        # plant (closedloop.fly): the primary's, so that until a trip the flight is its own
        self.mass = float(getattr(primary, "mass", fallback.mass))
        self.plant = getattr(primary, "plant", "hover")
        self.reset()

    def reset(self) -> None:
        self.primary.reset()
        self.fallback.reset()
        if self.monitor is not None:
            self.monitor.reset()
        self.trip_tick: int | None = None
        self.bits: list[int] = []
        self.flew: list[str] = []
        """Per tick: the primary's name, or ``pd`` / ``hold`` once handed over."""
        self._hold: RefSample | None = None

    def command(self, t: float, y: np.ndarray, q: np.ndarray, ref: RefSample) -> np.ndarray:
        k = len(self.bits)
        u = None
        if self.monitor is not None:
            bits = self.monitor.step(np.asarray(y, dtype=float) - ref.state)
        else:  # the exported step monitors what it reads: it runs every tick, even after a trip
            u = self.primary.command(t, y, q, ref)
            bits = self.onboard.flags if self.onboard is not None else 0
        self.bits.append(bits)
        if bits and self.trip_tick is None:
            self.trip_tick = k
            if self.mode == "hold":
                zero = np.zeros(3)
                self._hold = RefSample(p=np.array(y[:3], dtype=float), v=zero, a=zero)
        if self.trip_tick is None:
            self.flew.append(str(self.primary.name))
            cmd = u if u is not None else self.primary.command(t, y, q, ref)
        else:
            self.flew.append(self.mode)
            cmd = self.fallback.command(t, y, q, self._hold if self._hold is not None else ref)
        # the innovation monitor models the next measurement from the command flown
        du = np.asarray(cmd, dtype=float) - hover_input(self.fallback.mass)
        du = du - feedforward(ref, self.fallback.mass)
        if self.monitor is not None:
            self.monitor.command(du)
        elif self.onboard is not None and self.trip_tick is not None:
            self.onboard.flown(du)  # before the trip the step's own u is the one flown
        return cmd


def assured_controller(
    folder: Path, primary: PositionController, mass: float, pd: Any,
    K: Any = None, mode: Fallback = "pd",
) -> AssuredController:  # fmt: skip
    """The runtime-assured form of the synthesized controller in ``folder`` (flown as
    ``primary``): its own monitor (:func:`qsls.pipeline.control.monitor.monitor_of`, gate from
    its certificate; the exported step's when ``primary`` flies the exported C) and a PD
    fallback with gains ``pd`` (``K`` overrides the gain)."""
    cdir = load_controller_dir(folder)
    fallback = PDController(pd, mass, primary.dt)
    if K is not None:
        fallback.K = np.asarray(K, dtype=float)
    if exported_runtime(primary) is not None:
        return AssuredController(primary, fallback, None, mode)
    monitor = RuntimeMonitor(monitor_of(cdir), cdir.certificate.gate, innovation_of(cdir))
    return AssuredController(primary, fallback, monitor, mode)
