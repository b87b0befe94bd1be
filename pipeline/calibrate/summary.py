"""The calibration's summary (docs/calibration.md): ``calibration.json``'s line per candidate
and condition (its status, ``lambda_hat`` and what set it, its validation share against
``alpha``), and the console's lines read back from it."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pandas as pd

from qsls.pipeline.calibrate import core
from qsls.pipeline.calibrate.core import Outcome, Rule
from qsls.pipeline.calibrate.options import CalibrateOptions
from qsls.pipeline.premise.honest import clopper_pearson

SUMMARY_FILE = "calibration.json"


def summary_row(
    controller: str,
    condition: str,
    o: Outcome,
    validation: pd.DataFrame,
    rule: Rule,
    scores: pd.DataFrame | None = None,
) -> dict[str, Any]:
    """One candidate's line: its calibration, which premise quantity set ``lambda_hat``
    (:func:`qsls.pipeline.calibrate.core.set_by`, from its flights' ``scores``) and its validation share against
    ``alpha`` with its Clopper-Pearson interval."""
    g = o.check.guarantee if o.check is not None else None
    mine = _of(scores, controller, condition) if scores is not None else pd.DataFrame()
    row: dict[str, Any] = {
        "controller": controller,
        "condition": condition,
        "status": o.status,
        "reason": o.reason,
        "flights": len(o.scores.calibration),
        "lambda_hat": o.lambda_hat,
        "lambda_set_by": core.set_by(mine.to_dict(orient="records"), o.lambda_hat),
        "rho_star": g.rho_star if g else None,
        "tested_range": o.tested_range,
        "alpha": rule.alpha,
        "method": rule.method,
    }
    sel = _of(validation, controller, condition)
    n = len(sel)
    failed = ~sel["assumptions_hold"].astype(bool) if n else None
    k = int(failed.sum()) if failed is not None else 0
    lo, hi = clopper_pearson(k, n) if n else (math.nan, math.nan)
    broken = sel[failed]["first_failed"].value_counts().to_dict() if failed is not None else {}
    return row | {
        "validation_flights": n,
        "validation_broken": k,
        "validation_share": k / n if n else math.nan,
        "validation_ci": [lo, hi],
        "validation_first_failed": {str(a): int(b) for a, b in broken.items()},
        "validation_agrees": bool(n and lo <= rule.alpha),
    }


def _of(table: pd.DataFrame, controller: str, condition: str) -> pd.DataFrame:
    """The rows of one candidate in one condition."""
    if not len(table):
        return table
    return table[(table["controller"] == controller) & (table["condition"] == condition)]


def simulated_notice(options: CalibrateOptions) -> str:
    """The first line a simulated calibration prints: these are not the user's flights."""
    n = options.flights + options.range_flights + options.validation
    est = str(getattr(options.sim.vio, "kind", "emulator"))
    return (
        f"calibrate: flying {n} SIMULATED flights per candidate and condition (RotorPy, "
        f"{est} estimator, the configured reference and vehicle of {options.sim.vehicle.mass:g} "
        "kg), not your vehicle; to calibrate on your own flights give --recorded FOLDER "
        "(docs/vehicle.md)"
    )


def _unbounded(value: float | None) -> float:
    """A ``lambda_hat`` read from ``calibration.json``: ``null`` is no inflation covers, inf
    (docs/conventions.md#json)."""
    return math.inf if value is None else float(value)


def summary_lines(out: Path) -> list[str]:
    """The console's line per calibrated certificate (from ``calibration.json``)."""
    data = json.loads((Path(out) / SUMMARY_FILE).read_text())
    return [_line(r) for r in data["certificates"]]


def _line(r: Mapping[str, Any]) -> str:
    head = (
        f"{r['controller']} ({r['condition']}): {r['status']}, {r['flights']} calibration "
        f"flights, alpha {r['alpha']:g}, lambda_hat {_unbounded(r['lambda_hat']):.3g}"
    )
    if r.get("lambda_set_by"):
        head += f" (set by the {r['lambda_set_by']})"
    if r["rho_star"] is not None:
        head += f", rho* {r['rho_star']:.3g} (tested to {r['tested_range']:.3g})"
    if r["validation_flights"]:
        lo, hi = r["validation_ci"]
        head += (
            f"; validation: {r['validation_broken']} of {r['validation_flights']} broke "
            f"an assumption ({100 * lo:.0f}-{100 * hi:.0f} %)"
        )
    if r["reason"]:
        head += f"; {r['reason']}"
    return head
