"""The controller's own log of a flight, at its ticks (``ticks.parquet``; docs/calibration.md).

Every flight a synthesized controller flies keeps it (``qsls simulate``, the fly stage,
``qsls calibrate``), and a recorded flight gets one from its log (``qsls ingest --mass``,
docs/vehicle.md), so an auditor recomputes every assumption of its guarantee from it:
``t`` (s), the true state ``x_*`` and what the controller read ``y_*`` (``px .. vz``), the
absolute input ``u_*`` (``pitch, roll, thrust``, the paper's signs), the reference state
``r_*`` and its feedforward ``uff_*``, all in the controller's frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

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
