"""What a bound check must not take silently: controller folders without a certificate
inside a synth output, flights sampled at another ``dt`` than the controllers', and
"held-out" flights that are training flights."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from qsls.pipeline.control.artifacts import CERTIFICATE_FILE
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.evaluate.training import TrainingData
from qsls.pipeline.ingest.flight import states

if TYPE_CHECKING:
    from qsls.pipeline.evaluate.certified import ControllerBound


def skipped_controller_folders(folders: Sequence[Path]) -> list[str]:
    """Warnings for sub-folders of a synth output that hold no certificate (and so are not
    evaluated), instead of dropping them silently."""
    out = []
    for f in map(Path, folders):
        if f.is_dir() and not (f / CERTIFICATE_FILE).is_file():
            for p in sorted(q for q in f.iterdir() if q.is_dir() and not q.name.startswith(".")):
                if not (p / CERTIFICATE_FILE).is_file():
                    out.append(f"{p}: no {CERTIFICATE_FILE}, so this folder is not evaluated")
    return out


def flight_mismatches(
    held_out: Sequence[tuple[str, pd.DataFrame]],
    bounds: Sequence[ControllerBound],
    training: TrainingData,
) -> list[str]:
    """Refuse a flight whose ``dt`` is not the controllers' (one line); warn about a
    "held-out" flight that lies on the training states (distance 0 everywhere: a training
    flight, which says nothing about generalization)."""
    warnings = []
    dts = {round(float(b.certificate.get("dt", math.nan)), 9) for b in bounds}
    for name, df in held_out:
        t = df["t"].to_numpy(float)
        dt = float(np.median(np.diff(t))) if len(t) > 1 else math.nan
        for c_dt in dts:
            if math.isfinite(c_dt) and math.isfinite(dt) and abs(dt - c_dt) > 1e-6 * c_dt:
                raise InputError(
                    f"flight {name}: sampled every {dt:g} s but the controllers run at dt = "
                    f"{c_dt:g} s; ingest it with --dt {c_dt:g}"
                )
        x = states(df)
        ok = np.isfinite(x).all(axis=1)
        if ok.any() and float(training.nearest(x[ok])[0].max()) <= 1e-9:
            warnings.append(
                f"flight {name}: every state is a training state (distance 0): it looks like a "
                "training flight, not a held-out one"
            )
    return warnings
