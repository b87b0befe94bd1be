"""The fly stage's pure core (docs/evaluation.md, Flying the controllers): flown flights in,
tables and findings out; nothing is flown, read or written here (the stage,
:func:`qsls.pipeline.fly.stage.fly_evaluate`, flies, reads and writes).

:func:`fly_tables` takes the flown flights (:class:`qsls.pipeline.fly.flights.FlyOutcome`:
metrics and the controller's own log at its ticks), their ingested ``flight.parquet`` frames,
the controllers' bounds, their folders as read and the training data, and returns per
estimator (:func:`analyse`):

- the flight table and the mean per controller and condition (:mod:`qsls.pipeline.fly.tables`);
- the bound check of every ingested flight against its own controller's certificate (its
  condition's, with a calibration) and the robust reference bound (:func:`check_flights`);
- every assumption of the guarantee on the certified controllers' own flights;
- the point comparison with the paper (:func:`qsls.pipeline.fly.findings.compare_with_paper`)
  and the four findings paired by seed (:func:`qsls.pipeline.fly.paired.paired_findings`).

The primary estimator's (the first) are the stage's tables; with several estimators every
estimator's flights count in finding 3 and the by-estimator tables are added
(:mod:`qsls.pipeline.fly.estimators`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import pandas as pd

from qsls.pipeline.control.artifacts import ControllerDir
from qsls.pipeline.evaluate.certified import ControllerBound, certificate_for
from qsls.pipeline.evaluate.core import bound_check
from qsls.pipeline.evaluate.training import TrainingData
from qsls.pipeline.fly.bound_finding import finding3
from qsls.pipeline.fly.estimators import by_estimator_tables, findings_by_estimator
from qsls.pipeline.fly.estimators import findings_markdown as estimators_markdown
from qsls.pipeline.fly.findings import PAPER_CONTROLLERS, ROBUST_QR, compare_with_paper
from qsls.pipeline.fly.flights import FlyOutcome
from qsls.pipeline.fly.markdown import comparison_markdown
from qsls.pipeline.fly.options import FlyOptions
from qsls.pipeline.fly.paired import paired_findings, replace_finding
from qsls.pipeline.fly.tables import (
    assumption_table,
    bound_columns,
    flight_table,
    gain_norms,
    motion_parts,
    per_controller_table,
    premise_rows,
    true_lipschitz,
)


@dataclass(frozen=True)
class Flown:
    """What the stage flew and read, as the core takes it: the flights flown (runtime-assured
    ones left out), their ingested ``flight.parquet`` frames by flight name (a flight whose
    ingest failed is absent), the controllers' bounds (and their conditions' certificates,
    ``by_condition``), their folders as read and the training data."""

    outcomes: Sequence[FlyOutcome]
    ingested: Mapping[str, pd.DataFrame]
    bounds: Sequence[ControllerBound]
    training: TrainingData
    dirs: Mapping[Path, ControllerDir]
    by_condition: Mapping[tuple[str, str], ControllerBound] | None = None


@dataclass(frozen=True)
class Analysis:
    """One estimator's flights analysed as a single-estimator fly stage analyses them."""

    flights: pd.DataFrame
    checks: pd.DataFrame
    samples: pd.DataFrame
    assumptions: pd.DataFrame
    per: pd.DataFrame
    comparison: list[dict[str, Any]]
    findings: dict[str, Any]


@dataclass(frozen=True)
class FlyTables(Analysis):
    """What the fly stage writes: the primary estimator's tables (``assumptions`` every
    estimator's, ``estimator`` first, when there are several), ``findings.json``, the text of
    ``comparison.md`` and, with several estimators, the by-estimator tables by file name."""

    analyses: dict[str, Analysis]
    markdown: str
    by_estimator: dict[str, pd.DataFrame] = field(default_factory=dict)

    @classmethod
    def of(
        cls, primary: Analysis, analyses: dict[str, Analysis], markdown: str, **over: Any
    ) -> FlyTables:
        """The primary estimator's analysis as the stage's tables, ``over`` replacing some."""
        own = {f.name: getattr(primary, f.name) for f in fields(Analysis)}
        return cls(**{**own, **over}, analyses=analyses, markdown=markdown)


def check_flights(
    outcomes: Sequence[FlyOutcome],
    ingested: Mapping[str, pd.DataFrame],
    flights: pd.DataFrame,
    bounds: Sequence[ControllerBound],
    training: TrainingData,
    by_condition: Mapping[tuple[str, str], ControllerBound] | None = None,
) -> tuple[pd.DataFrame, pd.DataFrame, int | None]:
    """Bound check of every ingested flight (``ingested``: flight name -> its
    ``flight.parquet``; a flight whose ingest failed is absent) against its own controller's
    certificate (its condition's: :func:`certificate_for`) and the robust reference bound
    (``l1_robust``, else the first with a guarantee, index into ``bounds`` returned; its
    condition's too)."""
    held = [(o.name, ingested[o.name]) for o in outcomes if o.name in ingested]
    index = {b.name: i for i, b in enumerate(bounds)}
    ref_j = index.get(ROBUST_QR)
    if ref_j is None:
        ref_j = next((i for i, b in enumerate(bounds) if b.has_guarantee), None)
    every = list(bounds) + list((by_condition or {}).values())
    at = {id(b): j for j, b in enumerate(every)}
    named = {b.name: b for b in bounds}
    flown = dict(zip(flights["flight"], flights["controller"], strict=True))
    cond_of = dict(zip(flights["flight"], flights["condition"], strict=True))
    pairs = []
    for i, (name, _) in enumerate(held):
        cond = cond_of[name]
        mine = certificate_for(flown[name], cond, named, by_condition)
        ref = (
            certificate_for(bounds[ref_j].name, cond, named, by_condition)
            if ref_j is not None
            else None
        )
        for j in dict.fromkeys(at[id(x)] for x in (mine, ref) if x is not None):
            pairs.append((i, j))
    if not pairs:
        return pd.DataFrame(), pd.DataFrame(), ref_j
    by = [flown[name] for name, _ in held]
    checks, samples = bound_check(held, every, training, pairs=pairs, flown_by=by)
    checks.insert(3, "condition", checks["flight"].map(cond_of))
    return checks, samples, ref_j


def analyse(flown: Flown, options: FlyOptions, estimator: str = "emulator") -> Analysis:
    """Tables, bound checks, assumptions, the paper comparison and the paired findings of one
    estimator's flights (a flight checked against its condition's certificate where
    ``flown.by_condition`` holds one: :func:`certificate_for`)."""
    outcomes, ingested, bounds = flown.outcomes, flown.ingested, flown.bounds
    training, dirs, by_condition = flown.training, flown.dirs, flown.by_condition
    flights = flight_table(outcomes)
    checks, samples, ref_j = check_flights(
        outcomes, ingested, flights, bounds, training, by_condition
    )
    assumptions = assumption_table(outcomes, bounds, training, dirs, by_condition)
    per = bound_columns(per_controller_table(flights), checks)
    ref_bound = bounds[ref_j] if ref_j is not None else None
    comparison = compare_with_paper(
        per, checks, options.track_threshold_m, ref_bound, options.tie_rel,
        true_lipschitz(outcomes),
    )  # fmt: skip
    findings = paired_findings(
        flights, checks, ref_bound.name if ref_bound else None, PAPER_CONTROLLERS,
        options.track_threshold_m, motion_parts(options.sim), assumptions,
        estimator=estimator, strict=premise_rows(bounds), norms=gain_norms(bounds),
    )  # fmt: skip
    return Analysis(flights, checks, samples, assumptions, per, comparison, findings)


def fly_tables(flown: Flown, options: FlyOptions) -> FlyTables:
    """Every estimator's flights analysed (:func:`analyse`), the primary's as the stage's
    tables; with several, finding 3 counts every estimator's flights (the assumptions of all of
    them) and the by-estimator tables are added (module docstring)."""
    analyses: dict[str, Analysis] = {}
    for vio in options.estimators:
        mine = [o for o in flown.outcomes if o.estimator == vio]
        analyses[vio] = analyse(
            replace(flown, outcomes=mine), options, estimator=vio if mine else "emulator"
        )
    a = analyses[options.estimators[0]]
    if len(analyses) == 1:
        md = comparison_markdown(a.comparison, a.per, a.findings)
        return FlyTables.of(a, analyses, md)
    assumptions = a.assumptions
    if any(len(an.assumptions) for an in analyses.values()):
        assumptions = pd.concat(
            [an.assumptions.assign(estimator=vio) for vio, an in analyses.items()
             if len(an.assumptions)],
            ignore_index=True,
        )  # fmt: skip
    every = pd.concat([an.flights for an in analyses.values()], ignore_index=True)
    findings = replace_finding(
        findings_by_estimator(analyses),
        finding3(
            a.checks, every, None, assumptions if len(assumptions) else None,
            premise_rows(flown.bounds),
        ),
    )  # fmt: skip
    md = comparison_markdown(a.comparison, a.per, findings) + "\n" + estimators_markdown(analyses)
    return FlyTables.of(
        a, analyses, md, assumptions=assumptions, findings=findings,
        by_estimator=by_estimator_tables(analyses),
    )  # fmt: skip
