"""The fly stage with several estimators (``vio: [camera, emulator]``): every controller flown
with each, the results keyed by estimator and paired by controller, condition and seed.

The stage's own tables (``flights.parquet``, ``per_controller.parquet``,
``assumptions.parquet``, ``findings.json``, ``comparison.md``) are those of the primary
estimator (the first listed), written exactly as a single-estimator run writes them, so every
reader of a fly stage reads them unchanged. Beside them:

- ``flights_by_estimator.parquet``, ``per_controller_by_estimator.parquet``,
  ``assumptions_by_estimator.parquet``: every estimator's rows, an ``estimator`` column first;
- ``paired_by_estimator.parquet``: one row per controller, condition and seed, each metric
  once per estimator (``tracking_rms_m_camera``, ``tracking_rms_m_emulator``, ...), with the
  guarantee's verdict on that flight per estimator where the controller has one;
- ``findings.json`` gains ``estimator`` (the primary) and ``by_estimator``: each
  estimator's findings document (the single-estimator schema), so each finding's verdict
  can be read for both estimators side by side.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Protocol

import pandas as pd

from qsls.pipeline.fly.stats import paired_ratio


class EstimatorAnalysis(Protocol):
    """What these tables read of one estimator's analysis
    (:class:`qsls.pipeline.fly.core.Analysis`; the core imports this module, so this one states
    what it reads instead of importing it)."""

    @property
    def flights(self) -> pd.DataFrame: ...
    @property
    def assumptions(self) -> pd.DataFrame: ...
    @property
    def per(self) -> pd.DataFrame: ...
    @property
    def findings(self) -> dict[str, Any]: ...


KEYS = ["controller", "condition", "seed"]
PAIRED_METRICS = [
    "tracking_rms_m",
    "tracking_max_m",
    "perception_error_rms",
    "perception_error_max",
    "control_effort_rms",
    "crashed",
]
"""The metrics of each flight put side by side per estimator."""
FLIGHTS_FILE = "flights_by_estimator.parquet"
PAIRED_FILE = "paired_by_estimator.parquet"
PER_CONTROLLER_FILE = "per_controller_by_estimator.parquet"
ASSUMPTIONS_FILE = "assumptions_by_estimator.parquet"


def keyed(tables: Mapping[str, pd.DataFrame]) -> pd.DataFrame:
    """The tables stacked, each row keyed by its estimator (first column)."""
    parts = [
        t.assign(estimator=vio)[["estimator", *t.columns]] for vio, t in tables.items() if len(t)
    ]
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()


def paired(analyses: Mapping[str, EstimatorAnalysis]) -> pd.DataFrame:
    """One row per (controller, condition, seed) flown with every estimator: each estimator's
    metrics (``<metric>_<estimator>``) and, for a controller with a guarantee, whether every
    assumption held on that flight and the first that failed. Only flights flown with every
    estimator are kept (an inner join: paired by seed and condition)."""
    out: pd.DataFrame | None = None
    for vio, a in analyses.items():
        t = a.flights[[*KEYS, *PAIRED_METRICS]].copy()
        if len(a.assumptions):
            held = a.assumptions[[*KEYS, "assumptions_hold", "first_failed"]]
            t = t.merge(held, on=KEYS, how="left")
        else:
            t = t.assign(assumptions_hold=None, first_failed=None)
        t = t.rename(columns={c: f"{c}_{vio}" for c in t.columns if c not in KEYS})
        out = t if out is None else out.merge(t, on=KEYS, how="inner")
    return out if out is not None else pd.DataFrame()


RATIO_METRICS = ["tracking_rms_m", "perception_error_rms"]
"""The metrics compared across estimators as a paired ratio over seeds."""


def estimator_ratios(pairs: pd.DataFrame, a: str, b: str) -> pd.DataFrame:
    """Per condition and controller, for each of :data:`RATIO_METRICS`, the geometric mean over
    seeds of ``metric_a / metric_b`` (estimator ``a`` against ``b`` on the same controller,
    condition and seed) with the exp of the 95% t-interval of the log ratios
    (:func:`qsls.pipeline.fly.stats.paired_ratio`; no difference: 1). ``METRIC_n`` counts
    the pairs used (a crashed flight with a zero or missing metric drops its pair), ``n`` the
    pairs."""
    rows = []
    for (cond, ctrl), g in pairs.groupby(["condition", "controller"], sort=False):
        row: dict[str, Any] = {"condition": cond, "controller": ctrl}
        for m in RATIO_METRICS:
            iv = paired_ratio(g[f"{m}_{a}"], g[f"{m}_{b}"])
            row.update({f"{m}_ratio": iv.mean, f"{m}_lo": iv.lo, f"{m}_hi": iv.hi,
                        f"{m}_n": iv.n, "n": len(g)})  # fmt: skip
        rows.append(row)
    return pd.DataFrame(rows)


def findings_by_estimator(analyses: Mapping[str, EstimatorAnalysis]) -> dict[str, Any]:
    """The primary's findings document with ``estimator`` and ``by_estimator`` added."""
    primary = next(iter(analyses))
    return {
        **analyses[primary].findings,
        "estimator": primary,
        "by_estimator": {vio: a.findings for vio, a in analyses.items()},
    }


def findings_markdown(analyses: Mapping[str, EstimatorAnalysis]) -> str:
    """Each finding's verdict and effect per estimator, one row per finding."""
    vios = list(analyses)
    by_id: dict[str, dict[str, Any]] = {}
    claims: dict[str, str] = {}
    for vio, a in analyses.items():
        for f in a.findings.get("findings", []):
            by_id.setdefault(str(f["id"]), {})[vio] = f
            claims.setdefault(str(f["id"]), str(f["claim"]))

    def cell(f: dict[str, Any] | None) -> str:
        if f is None:
            return "-"
        eff = f.get("effect")
        return f"{f['verdict']} ({eff:.3g})" if isinstance(eff, float | int) else str(f["verdict"])

    lines = [
        "## Findings per estimator (same controllers, seeds and conditions)",
        "",
        "| finding | " + " | ".join(vios) + " |",
        "|---|" + "---|" * len(vios),
    ]
    for fid, claim in claims.items():
        lines.append(
            f"| {fid}. {claim} | " + " | ".join(cell(by_id[fid].get(v)) for v in vios) + " |"
        )
    return "\n".join(lines) + "\n"


def by_estimator_tables(analyses: Mapping[str, EstimatorAnalysis]) -> dict[str, pd.DataFrame]:
    """The keyed and paired tables of the module docstring, by file name."""
    return {
        FLIGHTS_FILE: keyed({v: a.flights for v, a in analyses.items()}),
        PER_CONTROLLER_FILE: keyed({v: a.per for v, a in analyses.items()}),
        ASSUMPTIONS_FILE: keyed({v: a.assumptions for v, a in analyses.items()}),
        PAIRED_FILE: paired(analyses),
    }


__all__ = [
    "ASSUMPTIONS_FILE",
    "FLIGHTS_FILE",
    "PAIRED_FILE",
    "PER_CONTROLLER_FILE",
    "RATIO_METRICS",
    "by_estimator_tables",
    "estimator_ratios",
    "findings_by_estimator",
    "findings_markdown",
    "keyed",
    "paired",
]
