"""The controller's own log of a flight, at its ticks (``ticks.parquet``; docs/calibration.md).

Every flight a synthesized controller flies keeps it (``qsls simulate``, the fly stage,
``qsls calibrate``), so an auditor recomputes every assumption of its guarantee from it:
``t`` (s), the true state ``x_*`` and what the controller read ``y_*`` (``px .. vz``), the
absolute input ``u_*`` (``pitch, roll, thrust``, the paper's signs), the reference state
``r_*`` and its feedforward ``uff_*``. The state ``x_k`` is the physics sample at the tick,
``uff_k = feedforward(r(t_k), mass)`` (:func:`qsls.pipeline.sim.controllers.feedforward`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from qsls.pipeline.core.references import Reference, ReferenceOptions
from qsls.pipeline.core.units import NS
from qsls.pipeline.sim.closedloop import FlightLog
from qsls.pipeline.sim.controllers import feedforward

TICKS_FILE = "ticks.parquet"
"""The controller's own log of a flight, at its ticks."""
STATE = ("px", "py", "pz", "vx", "vy", "vz")
INPUT = ("pitch", "roll", "thrust")


@dataclass(frozen=True)
class FlownLog:
    """A flight at the controller's ticks (``(k,)`` and ``(k, 6)`` / ``(k, 3)`` arrays)."""

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    u: np.ndarray
    ref: np.ndarray


@dataclass(frozen=True)
class TickLog(FlownLog):
    """A flight at the controller's ticks: ``t`` (k,), ``x``/``y``/``ref`` (k, 6), ``u``/``uff``
    (k, 3) (absolute input and the reference's feedforward, the paper's signs); a
    :class:`FlownLog`, so every assumption check reads it as it is."""

    uff: np.ndarray
    crashed: bool = False
    crash_reason: str = ""

    def frame(self) -> pd.DataFrame:
        cols: dict[str, np.ndarray] = {"t": self.t}
        for prefix, a, names in (("x", self.x, STATE), ("y", self.y, STATE), ("u", self.u, INPUT),
                                 ("r", self.ref, STATE), ("uff", self.uff, INPUT)):  # fmt: skip
            for j, n in enumerate(names):
                cols[f"{prefix}_{n}"] = a[:, j]
        return pd.DataFrame(cols)

    @classmethod
    def read(cls, path: Path) -> TickLog:
        """A ``ticks.parquet`` (or the folder holding it)."""
        f = path / TICKS_FILE if path.is_dir() else path
        df = pd.read_parquet(f)

        def block(prefix: str, names: Sequence[str]) -> np.ndarray:
            return df[[f"{prefix}_{n}" for n in names]].to_numpy(float)

        return cls(df["t"].to_numpy(float), block("x", STATE), block("y", STATE),
                   block("u", INPUT), block("r", STATE), block("uff", INPUT))  # fmt: skip


def _tick_states(flight: FlightLog) -> np.ndarray:
    """``x_k``: the physics sample at each controller tick (``(k, 6)``)."""
    ticks = flight.ctrl_t_ns
    if len(flight.t_ns) > 1:
        n_sub = max(1, round(flight.dt * NS / (flight.t_ns[1] - flight.t_ns[0])))
    else:
        n_sub = 1
    idx = np.minimum(np.arange(len(ticks)) * n_sub, len(flight.x) - 1)
    return np.asarray(flight.x[idx])


def _tick_feedforward(reference: ReferenceOptions, t: np.ndarray, mass: float) -> np.ndarray:
    """``uff_k = feedforward(r(t_k), mass)`` at the tick times ``t`` (s): ``(k, 3)``."""
    ref = Reference(reference)
    return np.array([feedforward(ref.sample(float(s)), mass) for s in t]).reshape(-1, 3)


def tick_log(flight: FlightLog, reference: ReferenceOptions) -> TickLog:
    """The flight's tick log (module docstring)."""
    t = flight.ctrl_t_ns / NS
    return TickLog(
        t, _tick_states(flight), flight.ctrl_y, flight.ctrl_u, flight.ctrl_ref,
        _tick_feedforward(reference, t, flight.mass), flight.crashed, flight.crash_reason or "",
    )  # fmt: skip
