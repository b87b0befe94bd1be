"""``qsls evaluate``, the held-out check's stage (docs/evaluation.md#the-bound-check): read the
error model, the certificates and the held-out flights, call the pure core
(:func:`~qsls.pipeline.evaluate.core.held_out_check`; one row is
:func:`~qsls.pipeline.evaluate.check.check_flight`), check every assumption on the flights a
controller flew itself (:mod:`.ownlog`) and write the stage folder through ``StageWriter``.

Outputs: ``evaluation.parquet`` (one row per flight and controller), ``evaluation.json`` (the
same rows, per-controller totals, warnings), ``samples.parquet`` (per-sample ``||e_k||``,
``d_k``, ``gamma_k``, ``d(x_hat_k)`` for the report) and figures.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from qsls.pipeline.core.artifacts import StageWriter, read_manifest, require_stage
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.errormodel.model import ErrorModel, load_error_model, resolve_model
from qsls.pipeline.evaluate import figures as plots
from qsls.pipeline.evaluate.certified import (
    calibration_of,
    certificate_for,
    check_model_hash,
    expand_controllers,
    load_bounds,
    load_conditioned,
)
from qsls.pipeline.evaluate.core import controller_totals, held_out_check
from qsls.pipeline.evaluate.mismatch import flight_mismatches, skipped_controller_folders
from qsls.pipeline.evaluate.nees import Nees, flight_nees
from qsls.pipeline.evaluate.options import CheckOptions, EvaluateOptions
from qsls.pipeline.evaluate.ownlog import own_log_assumptions
from qsls.pipeline.evaluate.table import Evaluation
from qsls.pipeline.evaluate.training import load_training
from qsls.pipeline.evaluate.twins import twin_warnings
from qsls.pipeline.evaluate.verdict import (
    ASSUMPTIONS_FILE,
    AssumptionVerdict,
    Verdict,
    combined,
    controller_promises,
    with_promises,
)
from qsls.pipeline.evaluate.weighted import weighted_bounds
from qsls.pipeline.ingest.flight import read_flight


def evaluate(
    flights: Sequence[Path],
    error_model: Path,
    controllers: Sequence[Path],
    options: EvaluateOptions,
    out: Path,
    *,
    force: bool = False,
    progress: Progress = NULL_PROGRESS,
    conditions: Sequence[str] | None = None,
    by_condition: Mapping[str, Sequence[Path]] | None = None,
    estimators: Sequence[str] | None = None,
) -> EvaluateResult:
    """The bound check of every held-out flight against every controller's certificate.

    ``conditions[i]``: flight ``i``'s perception condition (``''`` where not known, as for a
    recorded log); ``estimators[i]``: the estimator that made flight ``i``'s estimate
    (``camera``, ``emulator``; ``''`` where not known); ``by_condition``: per condition, the
    certificates a calibration wrote for it (``calibrate/<condition>/``). A flight is checked
    against its condition's certificate where there is one, else the controller's own, and the
    table's ``outside_calibration``
    says when that certificate was calibrated under other conditions (docs/calibration.md,
    "One certificate per condition")."""
    model_file, fit_dir = resolve_model(error_model)
    model = load_error_model(model_file)
    folders = expand_controllers(controllers)
    if not folders:
        raise InputError("no controllers given; pass at least one --controller folder")
    bounds = weighted_bounds(load_bounds(folders), model.state_scale)
    if options.flown_by is not None and options.flown_by not in {b.name for b in bounds}:
        raise InputError(
            f"--flown-by {options.flown_by}: not among the controllers "
            f"({', '.join(b.name for b in bounds)})"
        )
    warnings = [w for b in bounds if (w := check_model_hash(b, model_file, force=force))]
    training = load_training(fit_dir, model, options.state_scale)
    held_out = load_flights(flights)
    warnings += skipped_controller_folders(controllers)
    warnings += flight_mismatches(held_out, bounds, training)
    warnings += twin_warnings(flights, held_out, fit_dir)
    warnings += _not_ingested(flights)
    conds = _per_flight(conditions, len(held_out), "conditions")
    ests = _per_flight(estimators, len(held_out), "estimators")
    conditioned = load_conditioned(by_condition, [b.name for b in bounds], sorted(set(conds)))
    weighted = weighted_bounds(conditioned.values(), model.state_scale)
    conditioned = dict(zip(conditioned, weighted, strict=True))
    warnings += [
        m for b in conditioned.values() if (m := check_model_hash(b, model_file, force=force))
    ]
    every = [*bounds, *conditioned.values()]
    table, samples = held_out_check(
        held_out, bounds, conditioned, training, conds, ests,
        {b.folder: calibration_of(b.folder) for b in every},
        flown_by=options.flown_by, progress=progress,
    )  # fmt: skip
    assumptions = None
    if options.flown_by is not None:
        named = {b.name: b for b in bounds}
        own = [certificate_for(options.flown_by, c, named, conditioned) for c in conds]
        assumptions, missing = own_log_assumptions(flights, own, training, conds, ests)
        warnings += missing
    cond_folders = [b.folder for b in conditioned.values()]
    used = list(dict.fromkeys([model_file, *folders, *cond_folders, *map(Path, flights)]))
    return write_evaluation(
        out, table, samples, warnings, options=options, inputs=used, model=model, force=force,
        assumptions=assumptions, nees=vio_nees(flights, held_out),
        promises=controller_promises((b.name, b.certificate) for b in every),
    )  # fmt: skip


def _not_ingested(flights: Sequence[Path]) -> list[str]:
    """A warning for each held-out flight folder that ``qsls ingest`` did not write."""
    out = []
    for f in flights:
        try:
            require_stage(Path(f) if Path(f).is_dir() else Path(f).parent, "ingest")
        except InputError as exc:
            out.append(str(exc))
    return out


def _per_flight(values: Sequence[str] | None, n: int, what: str) -> list[str]:
    """One of ``values`` per flight (``''`` for each when not given)."""
    out = list(values) if values is not None else [""] * n
    if len(out) != n:
        raise InputError(f"{len(out)} {what} given for {n} flights")
    return out


@dataclass(frozen=True)
class EvaluateResult:
    out: Path
    table: pd.DataFrame
    warnings: tuple[str, ...]
    assumptions: pd.DataFrame | None = None
    """Every assumption on the flights a controller flew itself (``--flown-by``, from their
    tick logs); None when there are none."""
    nees: tuple[Nees, ...] = ()
    """The position NEES of each flight whose VIO recorded covariances (:mod:`.nees`)."""
    promises: Mapping[str, str] = field(default_factory=dict)
    """Each controller's promise, the sentence its verdict leads with (:mod:`.verdict`)."""

    def verdicts(self) -> list[Verdict | AssumptionVerdict]:
        """Each controller's verdict, led by its promise (:func:`.verdict.combined`)."""
        return with_promises(combined(self.table, self.assumptions), self.promises)

    def summary(self) -> dict[str, Any]:
        t = self.table
        out: dict[str, Any] = {
            "output": self.out.as_posix(),
            "flights": int(t["flight"].nunique()),
            "controllers": int(t["controller"].nunique()),
        }
        for c, g in t.groupby("controller", sort=False):
            # the per-sample curve gamma(d_k) checks the premise, not the controller: the
            # theorem's verdict is printed after the summary (verdict.py)
            out[f"{c}"] = (
                f"max ||e|| {g['max_error_norm'].max():.4g}; premise curve gamma(d_k): under "
                f"{100 * g['frac_under_gamma'].mean():.1f}%, max ratio {g['max_ratio'].max():.3g}; "
                f"gamma_strict {g['gamma_strict'].iloc[0]:.4g} (under "
                f"{100 * g['frac_under_gamma_strict'].mean():.1f}%)"
            )
        for n in self.nees:  # the estimator's own uncertainty, beside the bound
            out[f"VIO position NEES, {n.flight}"] = n.text()
        if self.warnings:
            out["warnings"] = len(self.warnings)
        return out


def load_flights(folders: Sequence[Path]) -> list[tuple[str, pd.DataFrame]]:
    """Read held-out flights (flight folders or ``flight.parquet`` files), unique names."""
    if not folders:
        raise InputError("no flights given; pass at least one --flights folder from 'qsls ingest'")
    out: list[tuple[str, pd.DataFrame]] = []
    seen: dict[str, int] = {}
    for f in folders:
        f = Path(f)
        df = read_flight(f)
        base = f.name if f.is_dir() else f.parent.name
        seen[base] = seen.get(base, 0) + 1
        name = base if seen[base] == 1 else f"{base}_{seen[base]}"
        out.append((name, df))
    return out


def vio_nees(
    folders: Sequence[Path], flights: Sequence[tuple[str, pd.DataFrame]]
) -> tuple[Nees, ...]:
    """The position NEES (:mod:`.nees`) of every flight whose VIO recorded covariances, with
    the alignment its ingest manifest keeps."""
    out = []
    for f, (name, frame) in zip(folders, flights, strict=True):
        folder = Path(f) if Path(f).is_dir() else Path(f).parent
        if "var_px" not in frame.columns:
            continue
        try:
            results = dict(read_manifest(folder).get("results") or {})
        except InputError:
            continue
        if (n := flight_nees(name, frame, results)) is not None:
            out.append(n)
    return tuple(out)


def write_evaluation(
    out: Path,
    table: pd.DataFrame,
    samples: pd.DataFrame,
    warnings: Sequence[str],
    *,
    options: EvaluateOptions,
    inputs: Sequence[Path],
    model: ErrorModel,
    force: bool,
    assumptions: pd.DataFrame | None = None,
    nees: tuple[Nees, ...] = (),
    promises: Mapping[str, str] | None = None,
) -> EvaluateResult:
    """Write the stage folder: ``evaluation.parquet``, ``evaluation.json`` (with each
    controller's ``promises``: :func:`~qsls.pipeline.evaluate.verdict.promise`),
    ``samples.parquet``, figures and, with ``assumptions``, ``assumptions.parquet``."""
    promised = dict(promises or {})
    with StageWriter(out, "evaluate", options=options, inputs=inputs, force=force) as w:
        if assumptions is not None:
            w.write_parquet(ASSUMPTIONS_FILE, assumptions)
        totals = write_tables(w, table, samples, warnings, model, options, {"promises": promised})
        w.results.update(
            {
                "flights": int(table["flight"].nunique()),
                "controllers": totals,
                "warnings": len(warnings),
            }
        )
        if nees:
            w.results["vio_position_nees"] = [n.as_dict() for n in nees]
    return EvaluateResult(
        out=Path(out), table=table, warnings=tuple(warnings), assumptions=assumptions, nees=nees,
        promises=promised,
    )  # fmt: skip


def write_tables(
    w: StageWriter,
    table: pd.DataFrame,
    samples: pd.DataFrame,
    warnings: Sequence[str],
    model: ErrorModel,
    options: CheckOptions,
    extra_json: dict[str, Any] | None = None,
    *,
    own_only: bool = False,
) -> list[dict[str, Any]]:
    """The bound check's files inside an open writer; returns the per-controller totals.
    ``own_only``: figures show each flight against the controller that flew it only."""
    totals = controller_totals(table) if len(table) else []
    w.write_parquet("samples.parquet", samples)
    doc = {
        "error_model": {
            "eps_e": model.eps_e,
            "R0": model.R0,
            "S_max": model.s_slope.max,
            "radius": model.radius,
            "state_scale": list(model.state_scale),
        },
        "controllers": totals,
        "rows": table.to_dict(orient="records"),
        "warnings": list(warnings),
        **(extra_json or {}),
    }
    Evaluation(table, doc).save(w)
    if options.figures and len(samples):
        sub = samples
        if own_only and "flown_by" in samples.columns:
            sub = samples[samples["controller"] == samples["flown_by"]]
        names = list(dict.fromkeys(sub["flight"]))[: options.max_figure_flights]
        sub = sub[sub["flight"].isin(names)]
        if not own_only:
            w.write_figure(
                plots.PERCEPTION_ERROR_FIGURE, plots.perception_error_figure(sub, options.smooth_s)
            )
        w.write_figure(plots.DISTANCE_FIGURE, plots.distance_figure(sub, model.radius))
    return totals
