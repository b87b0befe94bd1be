"""``qsls calibrate --recorded``: the candidates' premise calibrated on the user's own recorded
flights (docs/vehicle.md), with the simulated calibration's scores, quantile, status rules and
record (:mod:`qsls.pipeline.calibrate.stage`).

Each recorded flight (:mod:`qsls.pipeline.calibrate.recorded`) must be the candidate's own:
replayed through its taps and gate it gives the logged commands (else the command stops,
naming the flight and the first tick that differs). Calibration flights give the scores
``lambda_f`` (:func:`~qsls.pipeline.calibrate.stage.score_flight`), range flights theirs
without the reference's term (:func:`~qsls.pipeline.calibrate.stage.range_score`), and the
validation flights are checked against every assumption of the calibrated premise. The
conditions are the logs' (vehicle mass and hover thrust, estimator, tick, flight length);
the record lists each calibration flight's log sha256 (``calibration.logs``) in place of seeds.

Output: as ``qsls calibrate`` (``<condition>/<controller>/``, ``scores.parquet``,
``validation.parquet``, ``calibration.json``); the tick logs stay in their ingest folders.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from qsls.pipeline.calibrate.recorded import RecordedFlight, load_all, refuse_design
from qsls.pipeline.calibrate.stage import (
    SCORES_FILE,
    STAGE,
    SUMMARY_FILE,
    VALIDATION_FILE,
    CalibrateOptions,
    CalibrateResult,
    Outcome,
    calibrated_certificate,
    candidates,
    decide,
    fitted_seeds,
    offsets,
    range_score,
    record_monitor,
    score_flight,
    summary_row,
    taps_of,
)
from qsls.pipeline.calibrate.standin import standin_flights
from qsls.pipeline.control.artifacts import FlightEvidence, load_controller_dir
from qsls.pipeline.core.artifacts import StageWriter, check_output, sha256_file
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.core.ticks import TICKS_FILE
from qsls.pipeline.errormodel.model import load_error_model, resolve_model
from qsls.pipeline.evaluate.assumptions import check_assumptions
from qsls.pipeline.evaluate.certified import certified_premise
from qsls.pipeline.evaluate.flownby import flown_by
from qsls.pipeline.evaluate.training import load_training

DT_TOLERANCE = 0.01
"""A flight's tick may differ from the certificate's ``dt`` by this fraction (jitter)."""


def _check_dt(flights: list[RecordedFlight], folder: Path, dt: float) -> None:
    for f in flights:
        have = float(f.conditions["dt_s"])
        if abs(have - dt) > DT_TOLERANCE * dt:
            raise InputError(
                f"recorded flight {f.folder}: its controller ticked every {have:.4g} s, "
                f"{folder.name} is synthesized for dt {dt:g} s: not flown by this controller"
            )


def _conditions(
    flights: list[RecordedFlight], condition: str, estimator: str = ""
) -> dict[str, Any]:
    """What the certificate states of its calibration flights (their logs' conditions); the
    estimator is the estimate's topic unless named (the stand-in's: its simulated one)."""
    first = flights[0].conditions
    return {
        "source": "standin" if estimator else "recorded", "perception": condition,
        "estimator": estimator or first["estimator"], "estimate_topic": first["estimator"],
        "truth": first["truth"], "dt_s": first["dt_s"],
        "vehicle": {**first["vehicle"], "hover_thrust": _span(
            [f.conditions["vehicle"].get("hover_thrust") for f in flights])},
        "frame": first["frame"], "reference": _reference_family(flights),
        "duration_s": max(float(f.conditions["duration_s"]) for f in flights),
    }  # fmt: skip


def _span(values: list[Any]) -> list[float] | None:
    """``[low, high]`` of the numbers among ``values`` (None where there are none)."""
    nums = [float(v) for v in values if isinstance(v, int | float)]
    return [min(nums), max(nums)] if nums else None


def _reference_family(flights: list[RecordedFlight]) -> dict[str, list[float]]:
    """The range of each reference number over the flights (``[low, high]``): the references
    the calibration flew (:func:`qsls.pipeline.ingest.ticks.reference_summary`)."""
    refs = [f.conditions["reference"] for f in flights if f.conditions.get("reference")]
    keys = sorted({k for r in refs for k in r})
    return {k: [min(r[k] for r in refs), max(r[k] for r in refs)] for k in keys}


def calibrate_recorded(
    error_model: Path,
    synth_dir: Path,
    options: CalibrateOptions,
    out: Path,
    *,
    force: bool = False,
    progress: Progress = NULL_PROGRESS,
) -> CalibrateResult:
    """Prove, score, calibrate and validate every candidate on the recorded flights (module
    docstring); with ``options.source == "standin"`` the stand-in vehicle flies them first
    (:mod:`qsls.pipeline.calibrate.standin`)."""
    standin = options.source == "standin" and not options.recorded.given
    if not standin and not options.recorded.calibration:
        raise InputError(
            "calibrate: recorded range or validation flights need recorded calibration "
            "flights (--recorded FOLDER, repeated or comma-separated)"
        )
    if len(options.conditions) > 1:
        raise InputError(
            "calibrate: recorded flights are flown under the conditions they met: give one "
            "condition (--conditions NAME) to name them"
        )
    check_output(Path(out), force)
    model_file, fit_dir = resolve_model(error_model)
    folders = candidates(Path(synth_dir), options.controllers)
    if not folders:
        raise InputError(
            f"calibrate: {synth_dir} holds no robust controller whose design check passed; "
            "nothing to calibrate (see its certificates' checks)"
        )
    if standin:
        design = sorted(set(options.design_seeds) | set(fitted_seeds(fit_dir)))
        options = options.model_copy(update={"design_seeds": design})
        options.seed_lists()
    model = load_error_model(model_file)
    training = load_training(fit_dir, model, None)
    inputs = [model_file, *folders, *options.recorded.calibration, *options.recorded.range,
              *options.recorded.validation]  # fmt: skip
    with StageWriter(out, STAGE, options=options, inputs=inputs, force=force) as w:
        recorded = options.recorded
        if standin:
            dt = min(taps_of_dt(f) for f in folders)
            recorded = standin_flights(
                folders, options, w.path("standin"), dt,
                lambda s: offsets(s, options.tube, float(options.sim.reference.height)),
                progress,
            )  # fmt: skip
        flights = load_all({"calibration": recorded.calibration, "range": recorded.range,
                            "validation": recorded.validation})  # fmt: skip
        refuse_design(flights, fit_dir)
        owners = assign(flights, folders)
        rows, vrows, outcomes = [], [], []
        progress.start("recorded flights", total=len(flights))
        for folder in folders:
            mine = [f for f in flights if owners[f.name] == folder.name]
            if not any(f.role == "calibration" for f in mine):
                continue
            o, scored, checked = _one(folder, mine, options, training, w.path, standin)
            outcomes.append(o)
            rows += scored
            vrows += checked
            progress.advance(len(mine))
        progress.finish()
        if not outcomes:
            raise InputError(
                "calibrate: none of the candidates flew a calibration flight among those given"
            )
        scores, validation = pd.DataFrame(rows), pd.DataFrame(vrows)
        summary = [summary_row(o, validation, options) for o in outcomes]
        w.write_parquet(SCORES_FILE, scores)
        w.write_parquet(VALIDATION_FILE, validation)
        w.write_json(SUMMARY_FILE, {"alpha": options.alpha, "method": options.method,
                                    "delta": options.delta, "source": "recorded",
                                    "certificates": summary})  # fmt: skip
        w.results.update({"certificates": summary, "flown_by": owners})
    return CalibrateResult(Path(out), tuple(outcomes), validation, tuple(summary))


def assign(flights: Sequence[RecordedFlight], folders: Sequence[Path]) -> dict[str, str]:
    """Which candidate flew each flight (:func:`~qsls.pipeline.evaluate.flownby.flown_by`); a
    flight none of them flew is refused in one line, with the first candidate's reason."""
    owners: dict[str, str] = {}
    for f in flights:
        why = ""
        for folder in folders:
            p = flown_by(f.log, folder, f.mass, f.stamps)
            if p.flown:
                owners[f.name] = folder.name
                break
            why = why or f"{folder.name}: {p.reason}"
        if f.name not in owners:
            raise InputError(
                f"recorded flight {f.folder} ({f.role}): not flown by "
                f"{'any candidate' if len(folders) > 1 else 'this controller'} ({why})"
            )
    return owners


def _one(
    folder: Path,
    flights: list[RecordedFlight],
    options: CalibrateOptions,
    training: Any,
    path: Any,
    standin: bool = False,
) -> tuple[Outcome, list[dict[str, Any]], list[dict[str, Any]]]:
    """One candidate on its own flights: scores, the decision, the certificate, validation."""
    condition = options.conditions[0]
    premise = certified_premise(folder)
    if premise is None:
        raise InputError(f"calibrate: {folder.name} has no premise to calibrate")
    _check_dt(flights, folder, taps_of_dt(folder))
    scored: list[dict[str, Any]] = []
    for f in (f for f in flights if f.role != "validation"):
        parts = score_flight(f.log, premise, training.distance)
        if f.role == "range":
            parts["score"] = range_score(parts)
        scored.append({"flight": f.name, "role": f.role, "controller": folder.name,
                       "condition": condition, "log_sha256": f.log_sha256, "crashed": False,
                       **parts})  # fmt: skip
    s = [float(r["score"]) for r in scored if r["role"] == "calibration"]
    rs = [float(r["score"]) for r in scored if r["role"] == "range"]
    decision = decide(
        s, [float(r["reached"]) for r in scored], premise.numbers, taps_of(folder), options,
        range_scores=rs, broken=[r for r in scored if r["score"] == float("inf")],
    )  # fmt: skip
    o = Outcome.of(folder.name, condition, decision, s)
    calib = [f for f in flights if f.role == "calibration"]
    estimator = str(options.sim.vio.kind) if standin else ""
    conditions = _conditions([f for f in flights if f.role != "validation"], condition, estimator)
    target = path(f"{condition}/{folder.name}")
    root = path(condition).parent  # the output: a stand-in's tick logs are named inside it
    order = {"calibration": 0, "range": 1, "validation": 2}
    evidence = [_evidence(f, root) for f in sorted(flights, key=lambda f: order[f.role])]
    calibrated_certificate(
        folder, target, o, options, [], [r for r in scored if r["role"] == "calibration"],
        conditions, rs, logs=[f.log_sha256 for f in calib], duration=conditions["duration_s"],
        evidence=evidence,
    )  # fmt: skip
    record_monitor(target, [f.log for f in calib], options)
    c = certified_premise(target)
    checked = [
        {"flight": f.name, "controller": folder.name, "condition": condition,
         "log_sha256": f.log_sha256, **check_assumptions(f.log, c, training.distance)}
        for f in flights if f.role == "validation" and c is not None
    ]  # fmt: skip
    return o, scored, checked


def _evidence(f: RecordedFlight, root: Path) -> FlightEvidence:
    """A recorded flight's tick log and its sha256 (docs/verify.md): named relative to the
    output where it lies inside it (a stand-in's), else by its absolute path."""
    ticks = (f.folder / TICKS_FILE).resolve()
    where = ticks.relative_to(root.resolve()) if ticks.is_relative_to(root.resolve()) else ticks
    return FlightEvidence(flight=f.name, role=f.role, ticks=where.as_posix(),
                          sha256=sha256_file(ticks), log_sha256=f.log_sha256 or None)  # fmt: skip


def taps_of_dt(folder: Path) -> float:
    """The candidate's tick (s)."""
    return float(load_controller_dir(folder).controller.dt)
