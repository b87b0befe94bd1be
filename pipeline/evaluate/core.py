"""The held-out check's pure core (docs/evaluation.md#the-bound-check): the certificates'
numbers (:class:`~qsls.pipeline.evaluate.certified.ControllerBound`, already in the error
model's norms), the training states and the flights' tables in; the rows, the per-sample
frame and the per-controller totals out. No file is read or written here: the stage
(:mod:`.stage`) reads, calls :func:`held_out_check` and writes, as evo's ``ape()`` sits under
its ``run()``.

Each flight is checked against each controller's certificate, the one calibrated for the
flight's perception condition where there is one (docs/calibration.md, "One certificate per
condition"); one row is :func:`~qsls.pipeline.evaluate.check.check_flight`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from qsls.pipeline.control.calibration_record import Calibration
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.evaluate.certified import (
    ControllerBound,
    certificate_for,
    outside_calibration,
)
from qsls.pipeline.evaluate.check import check_flight, finite_samples
from qsls.pipeline.evaluate.training import TrainingData
from qsls.pipeline.ingest.flight import errors, states


def held_out_check(
    flights: Sequence[tuple[str, pd.DataFrame]],
    bounds: Sequence[ControllerBound],
    conditioned: Mapping[tuple[str, str], ControllerBound],
    training: TrainingData,
    conditions: Sequence[str],
    estimators: Sequence[str],
    calibrations: Mapping[Path, Calibration | None],
    *,
    flown_by: str | None = None,
    progress: Progress = NULL_PROGRESS,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Every flight against every controller, ``(rows, samples)``: flight ``i`` (perception
    ``conditions[i]``, estimator ``estimators[i]``, ``''`` where not known) is checked against
    :func:`~qsls.pipeline.evaluate.certified.certificate_for` each controller in ``bounds``
    (``conditioned``: per ``(condition, name)``, the calibration's certificate), and each row
    says whether that certificate was calibrated under other conditions (``calibrations``: each
    certificate folder's calibration record). ``flown_by``: the controller that flew every
    flight (``None``: recorded, the premise only)."""
    every = [*bounds, *conditioned.values()]
    at = {id(b): j for j, b in enumerate(every)}
    named = {b.name: b for b in bounds}
    pairs = [
        (i, at[id(b)])
        for i, cond in enumerate(conditions)
        for j in range(len(bounds))
        if (b := certificate_for(bounds[j].name, cond, named, conditioned)) is not None
    ]
    table, samples = bound_check(
        flights, every, training, pairs=pairs, flown_by=[flown_by] * len(flights),
        progress=progress,
    )  # fmt: skip
    cal = [calibrations[b.folder] for b in every]
    return with_conditions(table, flights, conditions, pairs, cal, estimators), samples


def bound_check(
    flights: Sequence[tuple[str, pd.DataFrame]],
    bounds: Sequence[ControllerBound],
    training: TrainingData,
    *,
    pairs: Sequence[tuple[int, int]] | None = None,
    flown_by: Sequence[str | None] | None = None,
    progress: Progress = NULL_PROGRESS,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Every flight against every controller (or the given ``(flight, controller)`` index
    pairs): ``(rows, samples)``. ``flown_by[i]`` names the controller that flew flight ``i``
    (``None``: recorded). Nearest distances are computed once per flight."""
    if pairs is None:
        pairs = [(i, j) for i in range(len(flights)) for j in range(len(bounds))]
    progress.start("bound check", total=len(pairs))
    nearest: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    rows, samples = [], []
    for i, j in pairs:
        name, df = flights[i]
        if i not in nearest:
            x = states(df)
            nearest[i] = training.nearest(x[finite_samples(name, x, errors(df))])
        by = flown_by[i] if flown_by is not None else None
        row, s = check_flight(name, df, bounds[j], training, nearest[i], by)
        rows.append(row)
        s.insert(1, "flown_by", by or "")
        samples.append(s)
        progress.advance()
    progress.finish()
    return pd.DataFrame(rows), pd.concat(samples, ignore_index=True)


def with_conditions(
    table: pd.DataFrame,
    flights: Sequence[tuple[str, pd.DataFrame]],
    conditions: Sequence[str],
    pairs: Sequence[tuple[int, int]],
    calibrations: Sequence[Calibration | None],
    estimators: Sequence[str] | None = None,
) -> pd.DataFrame:
    """The table with each row's flight ``condition`` and ``outside_calibration`` (why the
    certificate it was checked against, ``calibrations[j]`` its calibration record, was
    calibrated under other conditions, ``''`` when not:
    :func:`qsls.pipeline.evaluate.certified.outside_calibration`; ``estimators[i]``: flight
    ``i``'s estimator, ``''`` where not known)."""
    est = list(estimators) if estimators is not None else [""] * len(flights)
    span = [float(df["t"].iloc[-1] - df["t"].iloc[0]) if len(df) else 0.0 for _, df in flights]
    out = table.copy()
    out.insert(3, "condition", [conditions[i] for i, _ in pairs])
    out["outside_calibration"] = [
        outside_calibration(calibrations[j], conditions[i], span[i], est[i]) for i, j in pairs
    ]
    return out


def controller_totals(table: pd.DataFrame) -> list[dict[str, Any]]:
    """Per controller over all its flights: the worst case and the fractions."""
    out = []
    for c, g in table.groupby("controller", sort=False):
        out.append(
            {
                "controller": c,
                "flights": len(g),
                "gamma_strict": float(g["gamma_strict"].iloc[0]),
                "gamma_max": float(g["gamma"].max()),
                "max_error_norm": float(g["max_error_norm"].max()),
                "frac_under_gamma": float(g["frac_under_gamma"].mean()),
                "frac_under_gamma_strict": float(g["frac_under_gamma_strict"].mean()),
                "max_ratio": float(g["max_ratio"].max()),
                **_theorem_totals(g),
                "frac_premise_holds": float(g["frac_premise_holds"].mean()),
                "assumption_holds_all": bool(g["assumption_holds"].all()),
            }
        )
    return out


def _theorem_totals(g: pd.DataFrame) -> dict[str, Any]:
    """Over one controller's rows where the theorem applies (its own flights): how many, did
    the bound hold on all, the worst ``max ||e|| / gamma_nominal`` (None without such rows)."""
    own = g[g["theorem_applies"].astype(bool)] if "theorem_applies" in g else g.iloc[:0]
    if not len(own):
        return {"theorem_flights": 0, "bound_holds_all": None, "max_nominal_ratio": None}
    ratio = pd.to_numeric(own["nominal_ratio"], errors="coerce")
    return {
        "theorem_flights": len(own),
        "bound_holds_all": bool(own["bound_holds"].astype(bool).all()),
        "max_nominal_ratio": float(ratio.max()) if ratio.notna().any() else None,
        "max_a_nominal": float(own["a_nominal"].max()),
    }
