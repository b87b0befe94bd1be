"""The flight table every stage after ingest reads: ``flight.parquet``.

One row per sample on a common ``dt`` grid, VIO clock:
``t`` (s since the first sample), ``stamp_ns`` (int64), truth ``x_px .. x_vz``,
measurement ``y_px .. y_vz`` and perception error ``e_* = y_* - x_*``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from qsls.pipeline.core.errors import InputError

AXES = ("px", "py", "pz", "vx", "vy", "vz")
X_COLS = tuple(f"x_{a}" for a in AXES)
Y_COLS = tuple(f"y_{a}" for a in AXES)
E_COLS = tuple(f"e_{a}" for a in AXES)
COLUMNS = ("t", "stamp_ns", *X_COLS, *Y_COLS, *E_COLS)
FLIGHT_FILE = "flight.parquet"


def make_flight_frame(stamp_ns: np.ndarray, x: np.ndarray, y: np.ndarray) -> pd.DataFrame:
    """Build the flight table from stamps ``(n,)`` and truth/measurement ``(n, 6)``."""
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
    return pd.DataFrame(data, columns=list(COLUMNS))


def read_flight(folder_or_file: Path) -> pd.DataFrame:
    """Read ``flight.parquet`` from a flight folder (or the file itself), checking columns."""
    p = Path(folder_or_file)
    f = p / FLIGHT_FILE if p.is_dir() else p
    if not f.is_file():
        raise InputError(f"{p}: no {FLIGHT_FILE}; pass a folder written by 'qsls ingest'")
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
