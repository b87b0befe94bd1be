"""The training states of an error model, with a KD-tree for the distance of any state to
them (infinity norm of the error model's scaled state, docs/errormodel.md#weights)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.core.errors import InputError
from qsls.pipeline.errormodel.model import TRAINING_FILE, ErrorModel, load_training_states
from qsls.pipeline.ingest.flight import E_COLS, X_COLS, errors, states


@dataclass(frozen=True)
class TrainingData:
    """The states the error model was fitted on, with a KD-tree for nearest distances."""

    x: np.ndarray
    e: np.ndarray | None
    scale: np.ndarray
    tree: Any
    min_separation: float = 0.0
    """Slopes to the nearest training state only count beyond this distance (the error
    model's noise floor: closer pairs make slopes of noise over almost nothing)."""

    @classmethod
    def build(
        cls,
        x: np.ndarray,
        scale: Sequence[float],
        e: np.ndarray | None = None,
        min_separation: float = 0.0,
    ) -> TrainingData:
        from scipy.spatial import cKDTree

        scale_arr = np.asarray(scale, dtype=float)
        if scale_arr.shape != (6,) or np.any(scale_arr <= 0):
            raise InputError(f"state_scale must be 6 positive weights, got {list(scale_arr)}")
        x = np.asarray(x, dtype=float)
        if x.ndim != 2 or x.shape[1] != 6 or len(x) == 0:
            raise InputError("training states: expected a non-empty (n, 6) array")
        return cls(
            x=x, e=e, scale=scale_arr, tree=cKDTree(x * scale_arr),
            min_separation=float(min_separation),
        )  # fmt: skip

    def nearest(self, query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(d_k, i_k)``: infinity-norm distance in the scaled state to the nearest training
        state, and its index."""
        d, i = self.tree.query(np.asarray(query, dtype=float) * self.scale, k=1, p=np.inf)
        return np.asarray(d, dtype=float), np.asarray(i, dtype=np.int64)

    def distance(self, query: np.ndarray) -> np.ndarray:
        """``min_i ||W (q - x_i)||_inf`` for each row ``q`` of ``query``."""
        return self.nearest(query)[0]


def load_training(fit_dir: Path, model: ErrorModel, scale: Sequence[float] | None) -> TrainingData:
    """``FITDIR/training_states.parquet`` (columns ``x_px .. x_vz``, optionally ``e_*``)."""
    df = load_training_states(fit_dir)
    path = Path(fit_dir) / TRAINING_FILE
    missing = [c for c in X_COLS if c not in df.columns]
    if missing:
        raise InputError(
            f"{path}: missing columns {', '.join(missing)}; regenerate with 'qsls fit'"
        )
    if scale is not None and tuple(scale) != tuple(model.state_scale):
        raise InputError(
            f"state_scale {list(scale)} differs from the error model's "
            f"{list(model.state_scale)}: its S-slope is a slope in the model's norm; "
            "drop state_scale or refit with 'qsls fit --state-scale'"
        )
    e = errors(df) if all(c in df.columns for c in E_COLS) else None
    return TrainingData.build(
        states(df),
        model.state_scale,
        e,
        model.min_separation,
    )
