"""``qsls fly``: the paper's four controllers and SE3 flown side by side, every assumption
checked, the paper's findings tested paired by seed (docs/evaluation.md, Flying the
controllers).

The stage (:func:`fly_evaluate`) reads the error model and the controllers, flies
(:mod:`qsls.pipeline.fly.flights`: every controller, perception condition, seed and estimator;
each flight's bag ingested as a real log's), reads the ingested flights back and hands
everything to the pure core (:func:`qsls.pipeline.fly.core.fly_tables`: the tables, the bound
checks, every assumption, the paper comparison and the paired findings), then writes:
``flights.parquet``, ``per_controller.parquet``, ``assumptions.parquet``, ``findings.json``,
``comparison.md``, the bound check's ``evaluation.json`` and ``samples.parquet``, each flight's
``flights/<name>/ticks.parquet``, the figures, and with ``assured`` the runtime-assured flights
(``assured.parquet``; :mod:`qsls.pipeline.fly.assured`, docs/monitor.md, The fallback).

The four findings (paper, Results; :mod:`qsls.pipeline.fly.paired`):

1. regular perception: every controller tracks, and PD tracks best;
2. degraded perception: the robust ``qr``-cost controller (``l1_robust``) has the lowest
   perception error;
3. every controller's perception error stays below the bound;
4. the robust controllers react more softly than PD would on the same estimate.
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from qsls.pipeline.control.artifacts import ControllerDir, load_controller_dir
from qsls.pipeline.core.artifacts import StageWriter, check_output
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.core.workers import run_flights
from qsls.pipeline.errormodel.model import ErrorModel, load_error_model, resolve_model
from qsls.pipeline.evaluate.certified import (
    ControllerBound,
    check_model_hash,
    expand_controllers,
    load_bounds,
    load_conditioned,
    refuse_evidence_seeds,
)
from qsls.pipeline.evaluate.stage import EvaluateResult, write_tables
from qsls.pipeline.evaluate.training import TrainingData, load_training
from qsls.pipeline.evaluate.verdict import ASSUMPTIONS_FILE, controller_promises
from qsls.pipeline.evaluate.weighted import weighted_bounds
from qsls.pipeline.fly.assured import ASSURED_FILE, assured_comparison, catch_share
from qsls.pipeline.fly.core import Flown, FlyTables, fly_tables
from qsls.pipeline.fly.estimators import keyed
from qsls.pipeline.fly.figures import write_fly_figures
from qsls.pipeline.fly.flights import (
    FlyJob,
    FlyOutcome,
    make_jobs,
    monitored,
    pd_gain_of,
    run_job,
    select_controllers,
    tick_frame,
)
from qsls.pipeline.fly.items import FINDINGS_FILE
from qsls.pipeline.fly.options import FlyOptions
from qsls.pipeline.fly.tables import FLOWN_FILE, PER_CONTROLLER_TABLE, assured_table
from qsls.pipeline.ingest.flight import read_flight
from qsls.pipeline.sim.ticks import TICKS_FILE

COMPARISON_FILE = "comparison.md"
"""The findings and the per-controller metrics as Markdown (:mod:`qsls.pipeline.fly.markdown`)."""


@dataclass(frozen=True)
class FlyResult(EvaluateResult):
    """What ``qsls fly`` reports: the bound check's result plus the stage's own tables."""

    flights: pd.DataFrame = field(default_factory=pd.DataFrame)
    per_controller: pd.DataFrame = field(default_factory=pd.DataFrame)
    assumptions: pd.DataFrame = field(default_factory=pd.DataFrame)
    """Every assumption of the guarantee on each certified controller's own flights."""
    comparison: list[dict[str, Any]] = field(default_factory=list)
    findings: dict[str, Any] = field(default_factory=dict)
    wall_time_s: float = 0.0
    assured: pd.DataFrame = field(default_factory=pd.DataFrame)
    """The runtime-assured flights (``assured.parquet``), if flown."""

    def summary(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "output": self.out.as_posix(),
            "flights": len(self.flights),
            "crashed": int(self.flights["crashed"].sum()) if len(self.flights) else 0,
            "wall time (s)": round(self.wall_time_s, 1),
        }
        for _, r in self.per_controller.iterrows():
            out[f"{r['condition']}/{r['controller']}"] = (
                f"tracking RMS {r['tracking_rms_m']:.3f} m, ||e|| RMS {r['perception_error_rms']:.3f}, "
                f"max {r['perception_error_max']:.3f}, crashed {int(r['crashed'])}"
            )
        if len(self.assured):
            out["runtime-assured"] = (
                f"{int(self.assured['tripped'].sum())} of {len(self.assured)} flights handed "
                f"over to {self.assured['fallback'].iloc[0]}, "
                f"{int(self.assured['crashed'].sum())} crashed"
            )
        if self.warnings:
            more = (
                f" (+{len(self.warnings) - 3} more in evaluation.json)"
                if len(self.warnings) > 3
                else ""
            )
            out["warnings"] = "; ".join(self.warnings[:3]) + more
        return out

    def comparison_rows(self) -> tuple[list[str], list[list[Any]]]:
        """Per finding, paired by seed: the effect with its interval and the verdict, beside
        the point comparison's ``agrees`` (the details: ``comparison.md``)."""
        cols = ["finding (paper)", "effect [95% CI] (paper)", "verdict", "means agree"]
        by_id = {str(f["id"]): f for f in self.findings.get("findings", [])}
        rows = []
        for c in self.comparison:
            f = by_id.get(str(c["finding"]).partition(".")[0])
            eff, verdict = "-", "-"
            if f is not None and f["effect"] is not None:
                lo, hi = f["ci"]
                ci = f" [{lo:.3g}, {hi:.3g}]" if lo is not None and hi is not None else ""
                eff = f"{f['effect']:.3g}{ci} ({f['paper_direction']})"
                verdict = f["verdict"]
            rows.append([c["finding"], eff, verdict, c["agrees"]])
        return cols, rows


@dataclass(frozen=True)
class Setup:
    """What the stage reads before it flies: the error model, the training data, the
    controllers' bounds (``conditioned``: per ``(condition, name)``, the certificate calibrated
    for it), every certificate's folder as read, what each promises, and the warnings so far."""

    model_file: Path
    model: ErrorModel
    training: TrainingData
    folders: list[Path]
    bounds: list[ControllerBound]
    conditioned: dict[tuple[str, str], ControllerBound]
    dirs: dict[Path, ControllerDir]
    promises: Any
    warnings: list[str]

    @property
    def inputs(self) -> list[Path]:
        """The stage's input files and folders (its manifest's)."""
        extra = [b.folder for b in self.conditioned.values()]
        return list(dict.fromkeys([self.model_file, *self.folders, *extra]))


def read_setup(
    error_model: Path,
    controllers: Sequence[Path],
    options: FlyOptions,
    force: bool,
    by_condition: Mapping[str, Sequence[Path]] | None,
) -> Setup:
    """The error model, the controllers (``options.controllers`` of ``controllers``; with
    ``by_condition``, each condition's calibrated certificates), their bounds in the model's
    state weights and the training data; seeds a calibration flew are refused."""
    model_file, fit_dir = resolve_model(error_model)
    model = load_error_model(model_file)
    folders = select_controllers(expand_controllers(controllers), options.controllers)
    bounds = weighted_bounds(load_bounds(folders), model.state_scale)
    conditioned = load_conditioned(by_condition, [b.name for b in bounds], options.conditions)
    weighted = weighted_bounds(conditioned.values(), model.state_scale)
    conditioned = dict(zip(conditioned, weighted, strict=True))
    every = [*bounds, *conditioned.values()]
    promises = controller_promises((b.name, b.certificate) for b in every)
    refuse_evidence_seeds([*folders, *(b.folder for b in conditioned.values())], options.seeds)
    warnings = [m for b in every if (m := check_model_hash(b, model_file, force=force))]
    training = load_training(fit_dir, model, options.state_scale)
    dirs = {f: load_controller_dir(f) for f in dict.fromkeys(b.folder for b in every)}
    return Setup(model_file, model, training, folders, bounds, conditioned, dirs, promises,
                 warnings)  # fmt: skip


def fly_all(
    w: StageWriter, setup: Setup, options: FlyOptions, progress: Progress
) -> tuple[list[FlyOutcome], list[FlyJob]]:
    """Every flight flown (module docstring), each controller's own log written
    (``flights/<name>/ticks.parquet``, for an auditor to recompute from); the jobs beside."""
    specs: list[tuple[str, str]] = [(b.name, str(b.folder.resolve())) for b in setup.bounds]
    assured = [b.name for b in setup.bounds if monitored(b.folder)] if options.assured else []
    if options.se3:
        specs.append(("se3", "se3"))
    # scratch inside the stage's temporary folder: removed before it is published, and
    # reclaimed with it by the next writer if this process is killed (SIGKILL included)
    tmp_root = w.tmp / ".scratch"
    tmp_root.mkdir()
    try:
        jobs = make_jobs(
            specs, options, sims=w.path("sims") if options.keep_bags else tmp_root,
            flights=w.path("flights"), pd_gain=pd_gain_of(setup.folders), assured=assured,
            spec_in={k: str(b.folder.resolve()) for k, b in setup.conditioned.items()},
        )  # fmt: skip
        flown = run_flights(run_job, jobs, options, progress, "flying", "fly")
    finally:
        shutil.rmtree(tmp_root, ignore_errors=True)
    for o in flown:
        w.write_parquet(f"flights/{o.name}/{TICKS_FILE}", tick_frame(o))
    return flown, jobs


def flight_warnings(flown: Sequence[FlyOutcome]) -> list[str]:
    """A crash and a failed ingest, one line per flight."""
    out = []
    for o in flown:
        if o.metrics["crashed"]:
            out.append(f"{o.name}: crashed, flight ended safely ({o.metrics['crash_reason']})")
        if o.ingest_error:
            out.append(f"{o.name}: not bound-checked, ingest failed ({o.ingest_error})")
    return out


def write_assured(
    w: StageWriter,
    assured: Sequence[FlyOutcome],
    setup: Setup,
    options: FlyOptions,
    tables: FlyTables,
) -> tuple[pd.DataFrame, dict[str, Any]]:
    """``assured.parquet`` (:func:`qsls.pipeline.fly.tables.assured_table`); returns it and
    the comparison and catch share ``evaluation.json`` holds."""
    several = len(tables.analyses) > 1
    table = assured_table(
        assured, {b.name: b.status for b in setup.bounds}, options.fallback,
        {b.name: b.folder for b in setup.bounds}, setup.dirs, by_estimator=several,
        by_condition=setup.conditioned,
    )  # fmt: skip
    w.write_parquet(ASSURED_FILE, table)
    # with several estimators each assured flight meets its own estimator's flights
    flights = keyed({v: an.flights for v, an in tables.analyses.items()})
    comp = assured_comparison(flights if several else tables.flights, table)
    tripped = int(table["tripped"].sum()) if len(table) else 0
    w.results["assured"] = f"{tripped} of {len(table)} flights handed over"
    return table, {
        "assured": comp.to_dict(orient="records"),
        "monitor_catch": catch_share(tables.assumptions).to_dict(orient="records"),
    }


def write_stage(
    w: StageWriter, tables: FlyTables, setup: Setup, options: FlyOptions,
    outcomes: Sequence[FlyOutcome], assured_json: Mapping[str, Any],
) -> None:  # fmt: skip
    """The stage's tables, figures, ``evaluation.json`` and results (module docstring)."""
    for name, table in tables.by_estimator.items():
        w.write_parquet(name, table)
    w.write_parquet(FLOWN_FILE, tables.flights)
    w.write_parquet(ASSUMPTIONS_FILE, tables.assumptions)
    w.write_parquet(PER_CONTROLLER_TABLE, tables.per)
    w.write_json(FINDINGS_FILE, tables.findings)
    w.write_text(COMPARISON_FILE, tables.markdown)
    if options.figures:
        primary = [o for o in outcomes if o.estimator == options.estimators[0]]
        write_fly_figures(w, primary, options, tables.checks)
    extra_json = {
        "mode": "fly",
        "flights_table": tables.flights.to_dict(orient="records"),
        "per_controller": tables.per.to_dict(orient="records"),
        "comparison": tables.comparison,
        "assumptions": tables.assumptions.to_dict(orient="records"),
        "promises": setup.promises,
        **assured_json,
    }
    totals = write_tables(
        w, tables.checks, tables.samples, setup.warnings, setup.model, options, extra_json,
        own_only=True,
    )  # fmt: skip
    w.results.update(
        {
            "mode": "fly",
            "flights": len(tables.flights),
            "crashed": int(tables.flights["crashed"].sum()),
            **{f"finding_{c['finding'][0]}_agrees": c["agrees"] for c in tables.comparison},
            **{f"finding_{f['id']}_verdict": f["verdict"] for f in tables.findings["findings"]},
            "controllers": totals,
            "warnings": len(setup.warnings),
        }
    )
    if len(tables.analyses) > 1:
        w.results["estimators"] = list(options.estimators)


def fly_evaluate(
    error_model: Path,
    controllers: Sequence[Path],
    options: FlyOptions,
    out: Path,
    *,
    force: bool = False,
    progress: Progress = NULL_PROGRESS,
    by_condition: Mapping[str, Sequence[Path]] | None = None,
) -> FlyResult:
    """Fly, ingest, bound-check and compare (module docstring); writes the stage ``out``.
    ``by_condition``: per perception condition, controller folders certified for it (a
    calibration's ``calibrate/<condition>/``): a flight in that condition flies and is checked
    under that certificate (same taps), every other under the controller's own."""
    t0 = time.perf_counter()
    check_output(Path(out), force)
    setup = read_setup(error_model, controllers, options, force, by_condition)
    with StageWriter(out, "fly", options=options, inputs=setup.inputs, force=force) as w:
        flown, jobs = fly_all(w, setup, options, progress)
        setup.warnings.extend(flight_warnings(flown))
        # the assured flights are kept apart: every other table is what a run without them writes
        outcomes = [o for o, j in zip(flown, jobs, strict=True) if j.assured is None]
        ingested = {
            o.name: read_flight(Path(j.flight_dir))
            for o, j in zip(flown, jobs, strict=True)
            if j.assured is None and not o.ingest_error
        }
        read = Flown(
            outcomes, ingested, setup.bounds, setup.training, setup.dirs, setup.conditioned
        )
        tables = fly_tables(read, options)
        assured = pd.DataFrame()
        assured_json: dict[str, Any] = {}
        if options.assured:
            flew = [o for o, j in zip(flown, jobs, strict=True) if j.assured is not None]
            assured, assured_json = write_assured(w, flew, setup, options, tables)
        write_stage(w, tables, setup, options, outcomes, assured_json)
    return FlyResult(
        out=Path(out), table=tables.checks, assumptions=tables.assumptions,
        warnings=tuple(setup.warnings), flights=tables.flights, per_controller=tables.per,
        comparison=tables.comparison, findings=tables.findings,
        wall_time_s=time.perf_counter() - t0, assured=assured, promises=setup.promises,
    )  # fmt: skip


__all__ = ["FlyOptions", "FlyResult", "fly_evaluate"]
