"""The flight table every stage after ingest reads: ``flight.parquet``.

One row per sample on a common ``dt`` grid, VIO clock:
``t`` (s since the first sample), ``stamp_ns`` (int64), truth ``x_px .. x_vz``,
measurement ``y_px .. y_vz`` and perception error ``e_* = y_* - x_*``; when the VIO stream
is ``nav_msgs/Odometry`` with covariances (not all zero), their diagonals as recorded, in
the VIO's own frames, interpolated like ``y``: ``var_px .. var_rz`` (pose: position in
the odometry world frame, m^2; rotation about its axes, rad^2) and ``var_vx .. var_wz``
(twist, in the child frame: m^2/s^2, rad^2/s^2) (docs/ingest.md#covariances).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from qsls.pipeline.core.artifacts import read_manifest
from qsls.pipeline.core.errors import InputError

if TYPE_CHECKING:  # imported where used: ingest writes the table without pandas
    import pandas as pd
    import pyarrow as pa

AXES = ("px", "py", "pz", "vx", "vy", "vz")
X_COLS = tuple(f"x_{a}" for a in AXES)
Y_COLS = tuple(f"y_{a}" for a in AXES)
E_COLS = tuple(f"e_{a}" for a in AXES)
COLUMNS = ("t", "stamp_ns", *X_COLS, *Y_COLS, *E_COLS)
VAR_COLS = tuple(f"var_{a}" for a in ("px", "py", "pz", "rx", "ry", "rz",
                                      "vx", "vy", "vz", "wx", "wy", "wz"))  # fmt: skip
"""The VIO's covariance diagonals (pose, then twist), present only when it recorded them."""
FLIGHT_FILE = "flight.parquet"


def flight_columns(
    stamp_ns: np.ndarray, x: np.ndarray, y: np.ndarray, var: np.ndarray | None = None
) -> dict[str, np.ndarray]:
    """The flight table's columns, in ``COLUMNS`` order, from stamps ``(n,)`` and
    truth/measurement ``(n, 6)``: ``t = (stamp_ns - stamp_ns[0]) 1e-9``, ``e = y - x``; then
    the ``VAR_COLS`` from ``var`` ``(n, 12)`` when given."""
    stamp_ns = np.asarray(stamp_ns, dtype=np.int64)
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    if x.shape != (len(stamp_ns), 6) or y.shape != x.shape:
        raise ValueError(
            f"expected x and y of shape ({len(stamp_ns)}, 6), got {x.shape}, {y.shape}"
        )
    e = y - x
    data: dict[str, np.ndarray] = {
        "t": (stamp_ns - stamp_ns[0]).astype(float) * 1e-9 if len(stamp_ns) else np.zeros(0),
        "stamp_ns": stamp_ns,
    }
    for i, a in enumerate(AXES):
        data[f"x_{a}"] = x[:, i]
    for i, a in enumerate(AXES):
        data[f"y_{a}"] = y[:, i]
    for i, a in enumerate(AXES):
        data[f"e_{a}"] = e[:, i]
    if var is not None:
        var = np.asarray(var, dtype=float)
        for i, c in enumerate(VAR_COLS):
            data[c] = var[:, i]
    return data


def make_flight_frame(stamp_ns: np.ndarray, x: np.ndarray, y: np.ndarray) -> pd.DataFrame:
    """The flight table as a pandas DataFrame (:func:`flight_columns`)."""
    import pandas as pd

    return pd.DataFrame(flight_columns(stamp_ns, x, y), columns=list(COLUMNS))


def flight_table(
    stamp_ns: np.ndarray, x: np.ndarray, y: np.ndarray, var: np.ndarray | None = None
) -> pa.Table:
    """The flight table as a pyarrow Table (:func:`flight_columns`): what ingest writes.

    Importing pandas costs 0.15 s of a ``qsls ingest`` process; the table reads back with
    :func:`read_flight` as the same DataFrame :func:`make_flight_frame` builds (tested). The
    columns are wrapped as arrow buffers: ``pa.array`` would import pandas to ask whether
    its argument is a Series.
    """
    import pyarrow as pa

    arrays = []
    cols = flight_columns(stamp_ns, x, y, var)
    for c in cols.values():
        c = np.ascontiguousarray(c)
        typ = pa.from_numpy_dtype(c.dtype)
        arrays.append(pa.Array.from_buffers(typ, len(c), [None, pa.py_buffer(c)]))
    return pa.Table.from_arrays(arrays, names=list(cols))


def read_flight(folder_or_file: Path) -> pd.DataFrame:
    """Read ``flight.parquet`` from a flight folder (or the file itself), checking columns."""
    p = Path(folder_or_file)
    f = p / FLIGHT_FILE if p.is_dir() else p
    if not f.is_file():
        raise InputError(f"{p}: no {FLIGHT_FILE}; pass a folder written by 'qsls ingest'")
    import pandas as pd

    try:
        df = pd.read_parquet(f)
    except Exception as exc:  # pyarrow raises several types for a corrupt file
        raise InputError(f"{f}: cannot read parquet ({exc.__class__.__name__}: {exc})") from None
    missing = [c for c in COLUMNS if c not in df.columns]
    if missing:
        raise InputError(
            f"{f}: not a qsls flight table (missing columns {', '.join(missing)}); "
            "produce it with 'qsls ingest'"
        )
    return df


def states(df: pd.DataFrame) -> np.ndarray:
    return df.loc[:, list(X_COLS)].to_numpy(dtype=float)


def measurements(df: pd.DataFrame) -> np.ndarray:
    return df.loc[:, list(Y_COLS)].to_numpy(dtype=float)


def errors(df: pd.DataFrame) -> np.ndarray:
    return df.loc[:, list(E_COLS)].to_numpy(dtype=float)


def variances(df: pd.DataFrame) -> np.ndarray | None:
    """The VIO's recorded covariance diagonals ``(n, 12)`` (``VAR_COLS``), None without them."""
    if not all(c in df.columns for c in VAR_COLS):
        return None
    return df.loc[:, list(VAR_COLS)].to_numpy(dtype=float)


@dataclass(frozen=True)
class Flight:
    """A flight folder written by ``qsls ingest``: ``flight.parquet`` and what ingest recorded
    about it (its manifest's ``results``: clock offset, alignment, gaps, ``dt``)."""

    folder: Path
    frame: pd.DataFrame = field(repr=False)
    results: dict[str, Any] = field(default_factory=dict, repr=False)

    @property
    def name(self) -> str:
        return self.folder.name

    @property
    def dt(self) -> float:
        """The sample period (s): the manifest's ``dt``, else the median step of ``t``."""
        if "dt" in self.results:
            return float(self.results["dt"])
        t = self.frame["t"].to_numpy(dtype=float)
        return float(np.median(np.diff(t))) if len(t) > 1 else float("nan")

    def states(self) -> np.ndarray:
        return states(self.frame)

    def measurements(self) -> np.ndarray:
        return measurements(self.frame)

    def errors(self) -> np.ndarray:
        return errors(self.frame)

    @classmethod
    def load(cls, folder: Path) -> Flight:
        """Read a flight folder (or its ``flight.parquet``) and its manifest's results."""
        p = Path(folder)
        frame = read_flight(p)
        folder = p if p.is_dir() else p.parent
        try:
            results = dict(read_manifest(folder).get("results") or {})
        except InputError:
            results = {}  # a flight table without manifest (written by hand): data only
        return cls(folder, frame, results)
