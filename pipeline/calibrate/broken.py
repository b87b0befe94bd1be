"""Why no inflation covers a calibration: the premise quantity a flight broke beyond any
``lambda``, its value and the fix (docs/calibration.md#no-inflation-covers).

A flight's part ``value / limit`` is infinite when the certificate states a limit of 0 that
the flight exceeds (``Delta`` 0 from a fit without a reference, ``eps_w`` 0, ``m`` 0, ``eps``
and ``S`` both 0 where the error is not), or when one outlier exceeds ``eps_o`` (the gate
fixes it; no inflation moves it). Then ``lambda_hat = inf`` whatever the other flights did.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from qsls.pipeline.control import calibration as cal
from qsls.pipeline.control.guarantee import PremiseNumbers

NO_INFLATION = "a calibration flight broke a premise quantity no inflation covers"
"""The start of the refusal (the quantities follow it)."""


def _value(row: Mapping[str, Any], key: str) -> float | None:
    v = row.get(key)
    return float(v) if isinstance(v, int | float) and math.isfinite(float(v)) else None


def _what(quantity: str, rows: Sequence[Mapping[str, Any]], p: PremiseNumbers) -> str:
    """One quantity's clause: what it measured (the largest over ``rows``), against what, and
    the fix."""

    def top(key: str) -> str:
        vals = [v for r in rows if (v := _value(r, key)) is not None]
        return f"{max(vals):.3g}" if vals else "above 0"

    if quantity == "reference":
        return (
            f"reference: dist(x_ref) reaches {top('ref_max')} over Delta {p.delta:g} (an error "
            "model fitted without a reference): refit with qsls fit --reference (the reference "
            "flown) or state Delta with qsls synth --delta"
        )
    if quantity == "disturbance":
        return (
            f"disturbance: ||H^-1 w|| reaches {top('w_max')} over eps_w {p.eps_w:g}; state "
            "the disturbance bound (qsls synth --eps-w)"
        )
    if quantity == "outliers":
        if p.m == 0 and any((_value(r, "window_max") or 0) > 0 for r in rows):
            return (
                f"outliers: {top('window_max')} outliers in a window of T ticks over m 0; "
                "allow them (qsls synth --m)"
            )
        return (
            f"outliers: an outlier of {top('outlier_max')} exceeds eps_o {p.eps_o:g}, which "
            "the gate fixes and no inflation moves; raise the bound (qsls synth --eps-o, "
            "--gate)"
        )
    return (
        f"dense: the error is not 0 where eps + S dist is (eps {p.eps:g}, S {p.S:g}); state "
        "the error bound (qsls synth --eps-e, --S)"
    )


def broken_premise(rows: Sequence[Mapping[str, Any]], nominal: PremiseNumbers) -> str:
    """The refusal of a calibration whose ``lambda_hat`` is infinite because of flights
    ``rows`` (their parts, :data:`qsls.pipeline.control.calibration.SCORED`, and what they
    measured: ``ref_max``, ``w_max``, ``window_max``, ``outlier_max``): each infinite part
    once, with its largest value over the flights, the stated limit and the fix, e.g.
    ``reference: dist(x_ref) reaches 0.52 over Delta 0: ... (qsls fit --reference ...)``."""
    inf = [q for q in cal.SCORED if any(math.isinf(float(r.get(q, 0.0) or 0.0)) for r in rows)]
    if not inf:
        return NO_INFLATION
    clauses = []
    for q in inf:
        hit = [r for r in rows if math.isinf(float(r.get(q, 0.0) or 0.0))]
        n = f" ({len(hit)} flight{'s' if len(hit) != 1 else ''})"
        clauses.append(_what(q, hit, nominal).replace(":", n + ":", 1))
    return f"{NO_INFLATION}: " + "; ".join(clauses)
