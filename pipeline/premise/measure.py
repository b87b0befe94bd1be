"""The premise measured on the training data, beside its fit (docs/guarantee.md, Fitting the
premise so that all the data satisfy it): plain functions of arrays.

:func:`measure` splits the training errors into their dense and sparse parts
(:mod:`qsls.pipeline.premise.honest`), takes their weighted norms per channel group, fits
``S`` leave one flight out and the outlier count ``m``, and measures the realized disturbance;
:class:`TrainingStates` holds the states ``qsls fit`` saved beside ``error_model.yaml`` and
keeps one measurement per :class:`Spec`. The premise is chosen from here
(:func:`qsls.pipeline.premise.choose.choose_premise`), so the fit and the certificate share one
error model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.errormodel.disturbance import shaped_norm
from qsls.pipeline.errormodel.model import TRAINING_FILE, W_COLS
from qsls.pipeline.ingest.flight import E_COLS, X_COLS
from qsls.pipeline.premise import honest

ONES = (1.0,) * 6


@dataclass(frozen=True)
class Spec:
    """How the premise is measured: the norms, the channels, the clip, the window."""

    measure: str = "full"
    beta: float = math.inf
    state_scale: tuple[float, ...] = ONES
    error_scale: tuple[float, ...] = ONES
    radius: float = 1.0
    window: int = 20
    risk: float = 1e-3
    H: tuple[tuple[float, ...], ...] | None = None
    """The disturbance's input matrix: ``eps_w`` bounds ``||H^-1 w_k||_inf`` (None: ``H = I``)."""


@dataclass(frozen=True)
class Measured:
    """The premise quantities of the training data under a :class:`Spec` (arrays per sample)."""

    spec: Spec
    dense: np.ndarray
    """``|d_k|_e``."""
    outlier: np.ndarray
    """``||o_k||_inf`` (0 where none)."""
    flight: np.ndarray
    dist_other: np.ndarray
    w_norm: np.ndarray | None
    slope: honest.SlopeFit
    """``S = max_g S_g`` (:func:`honest.grouped_slope`)."""
    outliers: honest.OutlierFit
    groups: dict[str, np.ndarray] = field(default_factory=dict)
    """``|d_k,g|_e`` per channel group."""
    group_slopes: dict[str, honest.SlopeFit] = field(default_factory=dict)

    @property
    def eps(self) -> float:
        return float(self.dense.max())

    def eps_w(self, q: float | None = None) -> float | None:
        """The realized disturbance's maximum (or ``q``-th percentile) over the training steps."""
        if self.w_norm is None:
            return None
        w = self.w_norm[np.isfinite(self.w_norm)]
        if not len(w):
            return None
        return float(w.max() if q is None else np.percentile(w, q))


def measure(x: np.ndarray, e: np.ndarray, flight: np.ndarray, w_norm: np.ndarray | None,
            spec: Spec, environment: np.ndarray | None = None) -> Measured:  # fmt: skip
    """Split the errors, take their weighted norms and fit ``S`` (per channel group) and ``m``
    (pure: arrays in; distances only within an ``environment``,
    :func:`honest.other_flight_distances`)."""
    d, o = honest.split_errors(e, spec.beta, spec.measure)
    dense = honest.weighted_norm(d, spec.error_scale)
    dist = honest.other_flight_distances(x, flight, spec.state_scale, environment)
    groups = honest.group_norms(d, spec.error_scale, spec.measure)
    slope, per_group = honest.grouped_slope(groups, flight, dist, spec.radius)
    mag = np.abs(o).max(axis=1)
    outl = honest.fit_outliers(o, flight, spec.window, spec.risk)
    return Measured(spec, dense, mag, flight, dist, w_norm, slope, outl, groups, per_group)


@dataclass(frozen=True, eq=False)
class TrainingStates:
    """The training states an error model was fitted on, in memory: states ``x`` ``(n, 6)``,
    perception errors ``e`` ``(n, 6)``, flight codes ``(n,)`` and, when the fit measured it,
    the realized disturbance ``w`` ``(n, 6)``. ``source`` is what a certificate's premise
    records as where its shares were counted.

    :meth:`measured` keeps the premise measured per :class:`Spec`: a sweep resolves every grid
    point against one training set, and measuring (the other-flight KD-trees) is the costly
    part."""

    x: np.ndarray
    e: np.ndarray
    flight: np.ndarray
    w: np.ndarray | None = None
    source: str = "training data in memory"
    environment: np.ndarray | None = None
    """Environment code per sample (None: one environment): no distance crosses two."""
    _measured: dict[Spec, Measured] = field(
        default_factory=dict, repr=False, init=False, compare=False
    )

    def measured(self, spec: Spec) -> Measured:
        """:func:`measure` under ``spec`` (once per spec)."""
        if spec not in self._measured:
            w = None
            if self.w is not None:
                H = None if spec.H is None else np.asarray(spec.H, float)
                w = shaped_norm(self.w, H)
            self._measured[spec] = measure(self.x, self.e, self.flight, w, spec, self.environment)
        return self._measured[spec]

    @classmethod
    def from_frame(cls, df: Any, source: str = "training data in memory") -> TrainingStates:
        """From a table with the flight columns ``x_*``, ``e_*``, optionally ``flight``,
        ``environment`` and the disturbance ``w_*`` (the fit's ``training_states.parquet``)."""
        import pandas as pd

        x, e = df[list(X_COLS)].to_numpy(float), df[list(E_COLS)].to_numpy(float)
        codes = pd.factorize(df["flight"])[0] if "flight" in df.columns else np.zeros(len(df), int)
        w = df[list(W_COLS)].to_numpy(float) if all(c in df.columns for c in W_COLS) else None
        env = pd.factorize(df["environment"])[0] if "environment" in df.columns else None
        return cls(x, e, codes, w, source, env)


def training_beside(em_file: Path) -> TrainingStates | None:
    """The training states beside ``em_file`` (None when they are absent)."""
    import pandas as pd

    f = Path(em_file).parent / TRAINING_FILE
    if not f.is_file():
        return None
    return TrainingStates.from_frame(pd.read_parquet(f), f"{TRAINING_FILE} beside the error model")
