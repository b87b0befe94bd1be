"""The VIO's own uncertainty against the truth: the normalized estimation error squared (NEES)
of its recorded position covariance (docs/evaluation.md#the-vios-consistency-nees).

A VIO stream of ``nav_msgs/Odometry`` that records covariances leaves their diagonals in
``flight.parquet`` (``var_px, var_py, var_pz``: the position variances in the VIO's own
world frame, docs/ingest.md#covariances). The flight's position error ``e = y - x`` is in
the truth frame, after the alignment ``p' = R p + t`` ingest fitted (its manifest keeps
``R``), so in the VIO's frame it is ``R^T e``, and at every sample

    NEES_k = sum_i (R^T e_k)_i^2 / var_i,k,      i = x, y, z,

the squared error in units of the VIO's own variances. (With only the diagonal recorded
this is the NEES of ``diag(var)``; a VIO reporting correlated position errors is judged
without its off-diagonal terms.) If the VIO's covariance were right and its error Gaussian
with zero mean, ``NEES_k`` would follow a chi-square law with 3 degrees of freedom: mean 3,
above :data:`CHI2_3_95` on 5 % of the samples. A mean far above 3 says the VIO is
overconfident (its covariance too small for its errors), far below, that it is
pessimistic. The samples are correlated in time, so the mean is a description, not a test
at a stated level; and ``e`` includes the truth's own noise and is measured after an
alignment that absorbed its mean (both make NEES smaller).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from qsls.pipeline.ingest.flight import errors, variances

CHI2_3_95 = 7.814727903251179
"""The 95 % quantile of the chi-square law with 3 degrees of freedom (scipy's ``chi2.ppf``)."""


@dataclass(frozen=True)
class Nees:
    """The position NEES of one flight's VIO (module docstring)."""

    flight: str
    samples: int
    mean: float
    median: float
    share_above_95: float
    """Share of the samples above :data:`CHI2_3_95` (5 % for a consistent VIO)."""

    def as_dict(self) -> dict[str, Any]:
        return {
            "flight": self.flight,
            "samples": self.samples,
            "mean": self.mean,
            "median": self.median,
            "share_above_chi2_95": self.share_above_95,
        }

    def text(self) -> str:
        return (
            f"mean {self.mean:.3g} (consistent: 3), {100 * self.share_above_95:.1f} % of "
            f"{self.samples} samples above {CHI2_3_95:.2f} (consistent: 5 %)"
        )


def position_nees(frame: pd.DataFrame, rotation: np.ndarray) -> np.ndarray | None:
    """``NEES_k`` per sample (module docstring), NaN where a variance is not positive or a
    value is not finite; None when the flight records no covariances. ``rotation``: the
    alignment's ``R`` (ingest's manifest, ``results.alignment.rotation``)."""
    var = variances(frame)
    if var is None:
        return None
    e_vio = errors(frame)[:, :3] @ np.asarray(rotation, dtype=float)  # rows (R^T e)^T
    s2 = var[:, :3]
    ok = np.isfinite(e_vio).all(axis=1) & np.isfinite(s2).all(axis=1) & (s2 > 0).all(axis=1)
    out = np.full(len(frame), np.nan)
    out[ok] = np.sum(e_vio[ok] ** 2 / s2[ok], axis=1)
    return out


def flight_nees(name: str, frame: pd.DataFrame, results: dict[str, Any]) -> Nees | None:
    """The flight's :class:`Nees`; None without covariances, an alignment in its manifest,
    or a sample where it is defined."""
    rotation = (results.get("alignment") or {}).get("rotation")
    if rotation is None:
        return None
    nees = position_nees(frame, np.asarray(rotation, dtype=float))
    if nees is None:
        return None
    v = nees[np.isfinite(nees)]
    if not len(v):
        return None
    return Nees(
        flight=name,
        samples=len(v),
        mean=float(np.mean(v)),
        median=float(np.median(v)),
        share_above_95=float(np.mean(v > CHI2_3_95)),
    )
