"""A held-out flight that is a training flight's twin: the same flight data as a flight the
error model was fitted on, found as ``qsls fit`` finds a pair it refuses
(:func:`qsls.pipeline.errormodel.fit.same_motion`, docs/evaluation.md#which-flights). The
bound checked on it is checked on the model's own data, so ``qsls evaluate`` warns, naming
both.

The training flights are the fit's inputs where their folders still hold ``flight.parquet``
(full flights, with their stamps); a training flight whose folder is gone is compared through
the fit's ``training_states.parquet`` (its kept samples, ``t`` and ``x``).
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from qsls.pipeline.core.artifacts import read_manifest
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.errormodel.fit import same_motion
from qsls.pipeline.errormodel.model import load_training_states
from qsls.pipeline.ingest.flight import FLIGHT_FILE, X_COLS, read_flight, states


def _key(x: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(x, dtype=float).tobytes()).hexdigest()


def training_flights(fit_dir: Path) -> list[tuple[str, Path | None, pd.DataFrame]]:
    """``(name, folder or None, frame)`` of each flight the model in ``fit_dir`` was fitted
    on (module docstring)."""
    out: list[tuple[str, Path | None, pd.DataFrame]] = []
    try:
        inputs = read_manifest(fit_dir).get("inputs", [])
    except InputError:
        inputs = []
    for i in inputs:
        p = Path(str(i.get("path", ""))) if isinstance(i, dict) else Path()
        if (p / FLIGHT_FILE).is_file():
            try:
                out.append((p.name, p, read_flight(p)))
            except InputError:
                continue
    found = {n for n, _, _ in out}
    try:
        df = load_training_states(fit_dir)
    except InputError:
        return out
    if "flight" in df.columns and "t" in df.columns and all(c in df.columns for c in X_COLS):
        for name, g in df.groupby("flight", sort=False):
            if str(name) not in found:
                out.append((str(name), None, g.reset_index(drop=True)))
    return out


def _same_rows(held: pd.DataFrame, train: pd.DataFrame) -> bool:
    """Every kept training sample is a sample of ``held`` (the same ``t``, the same state):
    the fit kept some of the flight's samples, so a whole-flight hash cannot match."""
    th, tt = held["t"].to_numpy(float), train["t"].to_numpy(float)
    if len(tt) < 20 or len(th) < len(tt):
        return False
    k = np.clip(np.searchsorted(th, tt), 0, len(th) - 1)
    return bool(np.array_equal(states(held)[k], states(train)) and np.allclose(th[k], tt))


def twin_warnings(flights: Sequence[Path], held_out: Sequence[tuple[str, Any]], fit_dir: Path
                  ) -> list[str]:  # fmt: skip
    """One warning per held-out flight that is a training flight's twin: the same folder,
    the same ground truth (``x`` byte for byte, or every kept training sample), or the same
    motion at the same times (:func:`~qsls.pipeline.errormodel.fit.same_motion`)."""
    training = training_flights(fit_dir)
    keys = {_key(states(fr)): j for j, (_, folder, fr) in enumerate(training) if folder}
    out = []
    for path, (name, df) in zip(flights, held_out, strict=True):
        folder = Path(path) if Path(path).is_dir() else Path(path).parent
        how = None
        for j, (tname, tfolder, tframe) in enumerate(training):
            if tfolder is not None and tfolder.resolve() == folder.resolve():
                how = "the same folder"
            elif keys.get(_key(states(df))) == j or (tfolder is None and _same_rows(df, tframe)):
                how = "the same ground truth"
            elif same_motion(df, tframe):
                how = "the same motion at the same times"
            if how:
                out.append(
                    f"evaluate a flight the fit did not see: held-out flight '{name}' "
                    f"({path}) is training flight '{tname}'"
                    + (f" ({tfolder})" if tfolder is not None else "")
                    + f"'s twin ({how}), so its bound is checked on the model's own data"
                )
                break
    return out
