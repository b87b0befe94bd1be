"""The controller's own log of a flight, at its ticks (``ticks.parquet``; docs/calibration.md).

Every flight a synthesized controller flies keeps it (``qsls simulate``, the fly stage,
``qsls calibrate``), so an auditor recomputes every assumption of its guarantee from it:
``t`` (s), the true state ``x_*`` and what the controller read ``y_*`` (``px .. vz``), the
absolute input ``u_*`` (``pitch, roll, thrust``, the paper's signs), the reference state
``r_*`` and its feedforward ``uff_*``. The state ``x_k`` is the physics sample at the tick,
``uff_k`` the feedforward the controller added (the model's, for its mass and plant:
:meth:`qsls.pipeline.core.references.Reference.feedforward`).
"""

from __future__ import annotations

import numpy as np

from qsls.pipeline.core.ticks import INPUT as INPUT
from qsls.pipeline.core.ticks import STATE as STATE
from qsls.pipeline.core.ticks import TICKS_FILE as TICKS_FILE
from qsls.pipeline.core.ticks import FlownLog as FlownLog
from qsls.pipeline.core.ticks import TickLog
from qsls.pipeline.core.units import NS
from qsls.pipeline.sim.closedloop import FlightLog


def _tick_states(flight: FlightLog) -> np.ndarray:
    """``x_k``: the physics sample at each controller tick (``(k, 6)``)."""
    ticks = flight.ctrl_t_ns
    if len(flight.t_ns) > 1:
        n_sub = max(1, round(flight.dt * NS / (flight.t_ns[1] - flight.t_ns[0])))
    else:
        n_sub = 1
    idx = np.minimum(np.arange(len(ticks)) * n_sub, len(flight.x) - 1)
    return np.asarray(flight.x[idx])


def tick_log(flight: FlightLog, sha256: str = "") -> TickLog:
    """The flight's tick log (module docstring), naming the controller that flew (and its
    ``controller.npz``'s ``sha256`` where the caller knows it)."""
    assert flight.ctrl_uff is not None, "every flight records the feedforward it flew"
    return TickLog(
        flight.ctrl_t_ns / NS, _tick_states(flight), flight.ctrl_y, flight.ctrl_u,
        flight.ctrl_ref, flight.ctrl_uff, flight.crashed, flight.crash_reason or "",
        controller=flight.controller, controller_sha256=sha256,
    )  # fmt: skip
