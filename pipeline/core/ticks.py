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
from typing import TYPE_CHECKING

import numpy as np

from qsls.pipeline.core.errors import InputError

if TYPE_CHECKING:
    import pandas as pd

TICKS_FILE = "ticks.parquet"
"""The controller's own log of a flight, at its ticks."""
STATE = ("px", "py", "pz", "vx", "vy", "vz")
INPUT = ("pitch", "roll", "thrust")
_BLOCKS = (("x", STATE), ("y", STATE), ("u", INPUT), ("r", STATE), ("uff", INPUT))
MIN_TICKS = 10
"""Fewer ticks are no flight: every assumption would hold on nothing (one second at 10 Hz)."""


@dataclass(frozen=True)
class FlownLog:
    """A flight at the controller's ticks (``(k,)`` and ``(k, 6)`` / ``(k, 3)`` arrays): the
    reference ``ref`` and the feedforward ``uff`` the controller added are what the proof's
    deviation coordinates subtract (docs/guarantee.md)."""

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    u: np.ndarray
    ref: np.ndarray
    uff: np.ndarray


@dataclass(frozen=True)
class TickLog(FlownLog):
    """A flight at the controller's ticks: ``t`` (k,), ``x``/``y``/``ref`` (k, 6), ``u``/``uff``
    (k, 3) (absolute input and the reference's feedforward, the paper's signs); a
    :class:`FlownLog`, so every assumption check reads it as it is."""

    crashed: bool = False
    crash_reason: str = ""
    controller: str = ""
    """The controller that flew (its name; kept in the file's metadata)."""
    controller_sha256: str = ""
    """Its ``controller.npz``'s sha256, where the writer knew it."""

    def frame(self) -> pd.DataFrame:
        import pandas as pd  # deferred: ingest imports this module and reads no pandas

        cols: dict[str, np.ndarray] = {"t": self.t}
        for prefix, a, names in (("x", self.x, STATE), ("y", self.y, STATE), ("u", self.u, INPUT),
                                 ("r", self.ref, STATE), ("uff", self.uff, INPUT)):  # fmt: skip
            for j, n in enumerate(names):
                cols[f"{prefix}_{n}"] = a[:, j]
        df = pd.DataFrame(cols)
        identity = {"controller": self.controller, "controller_sha256": self.controller_sha256}
        df.attrs.update({k: v for k, v in identity.items() if v})
        return df

    @classmethod
    def read(cls, path: Path) -> TickLog:
        """A ``ticks.parquet`` (or the folder holding it), refused in one line
        (:class:`~qsls.pipeline.core.errors.InputError`) where it is unreadable, lacks a column,
        holds fewer than :data:`MIN_TICKS` ticks, a time that does not increase, or a value
        that is not finite: a check must never pass on what a log does not hold."""
        import pandas as pd  # deferred: ingest imports this module and reads no pandas

        f = path / TICKS_FILE if path.is_dir() else path
        try:
            df = pd.read_parquet(f)
        except (OSError, ValueError) as exc:  # pyarrow's errors are ValueErrors or OSErrors
            raise InputError(f"{f}: not a readable tick log ({_first_line(exc)})") from None
        want = ["t", *(f"{p}_{n}" for p, names in _BLOCKS for n in names)]
        missing = [c for c in want if c not in df.columns]
        if missing:
            raise InputError(
                f"{f}: not a tick log: no column {', '.join(missing[:4])}"
                + (f" (and {len(missing) - 4} more)" if len(missing) > 4 else "")
            )
        if len(df) < MIN_TICKS:
            raise InputError(f"{f}: {len(df)} ticks; a tick log holds {MIN_TICKS} at least")
        values = df[want].to_numpy(float)
        bad = ~np.isfinite(values)
        if bad.any():
            k, j = (int(v[0]) for v in np.nonzero(bad))
            raise InputError(f"{f}: {want[j]} is {values[k, j]} at tick {k}: not a flown value")
        t = values[:, 0]
        if np.any(np.diff(t) <= 0):
            k = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
            raise InputError(f"{f}: t does not increase at tick {k} ({t[k - 1]:g}, {t[k]:g} s)")

        def block(prefix: str, names: Sequence[str]) -> np.ndarray:
            return df[[f"{prefix}_{n}" for n in names]].to_numpy(float)

        return cls(t, block("x", STATE), block("y", STATE), block("u", INPUT),
                   block("r", STATE), block("uff", INPUT),
                   controller=str(df.attrs.get("controller", "")),
                   controller_sha256=str(df.attrs.get("controller_sha256", "")))  # fmt: skip

    def off_rate(self, dt: float, tolerance: float = 0.01) -> str:
        """Why the ticks are not a controller's of period ``dt`` ('' when they are): every
        step within ``tolerance`` of ``dt``."""
        step = np.diff(self.t)
        off = np.abs(step - dt) > tolerance * dt
        if not off.any():
            return ""
        k = int(np.flatnonzero(off)[0])
        return f"its ticks are {step[k]:.4g} s apart at tick {k + 1}, not the controller's {dt:g} s"


def _first_line(exc: BaseException) -> str:
    return (str(exc).strip().splitlines() or [type(exc).__name__])[0][:200]
