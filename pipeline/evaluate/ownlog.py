"""The controller's own log on a held-out flight (docs/evaluation.md#the-bound-check,
``--flown-by``): where a flight's tick log is, whether the controller being checked flew it
(the name and sha256 the log states, its ticks at the controller's ``dt``, the replay for a
vehicle's log), and every assumption of that controller's guarantee checked on it
(:mod:`.assumptions`). Reads the flight folders' tick logs and manifests and the
certificates' premises; writes nothing."""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from qsls.pipeline.control.artifacts import load_controller_dir
from qsls.pipeline.core.artifacts import read_manifest
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.evaluate.assumptions import check_assumptions
from qsls.pipeline.evaluate.certified import (
    ControllerBound,
    outside_calibration,
    premise_of,
)
from qsls.pipeline.evaluate.conditions import flight_conditions
from qsls.pipeline.evaluate.flownby import flown_by
from qsls.pipeline.evaluate.training import TrainingData
from qsls.pipeline.sim.simulate import TRUTH_FILE
from qsls.pipeline.sim.ticks import TICKS_FILE, TickLog


def own_log_of(folder: Path) -> tuple[Path | None, str]:
    """Where flight ``folder``'s tick log is, and the controller that flew it (``''`` when not
    recorded): the folder's own ``ticks.parquet`` (the fly stage's and the calibration's
    flights), else the one beside the bag its ingest read (``qsls simulate``), whose
    ``truth.json`` names the controller."""
    if (folder / TICKS_FILE).is_file():
        return folder / TICKS_FILE, ""
    try:
        inputs = read_manifest(folder).get("inputs") or []
    except InputError:
        return None, ""
    for i in inputs:
        src = Path(str(i.get("path", ""))).parent if isinstance(i, dict) else None
        if src is not None and (src / TICKS_FILE).is_file():
            try:
                who = json.loads((src / TRUTH_FILE).read_text()).get("controller", "")
            except (OSError, ValueError, AttributeError):
                who = ""  # no readable truth.json: who flew it is not recorded
            return src / TICKS_FILE, str(who or "")
    return None, ""


def simulated_conditions(ticks: Path) -> dict[str, Any] | None:
    """The recorded conditions of the simulated flight whose tick log is ``ticks`` (vehicle,
    reference, VIO emulator: :func:`qsls.pipeline.evaluate.conditions.flight_conditions`),
    read from the simulate folder's manifest beside it; None where the log is not a
    simulation's (a recorded flight states its conditions in its ingest manifest)."""
    try:
        opts = read_manifest(ticks.parent).get("options")
    except InputError:
        return None
    if not isinstance(opts, dict) or not isinstance(opts.get("vehicle"), dict):
        return None
    return flight_conditions(opts)


def own_log(
    folder: Path, ticks: Path, who: str, bound: ControllerBound
) -> tuple[TickLog | None, str]:
    """Flight ``folder``'s tick log if ``bound``'s controller flew it, else why not: the
    controller ``truth.json`` names (``who``), the one the log names (name and sha256), its
    ticks at the controller's ``dt``, and for a vehicle's log the replay
    (:func:`~qsls.pipeline.evaluate.flownby.flown_by`). A log that cannot be read is named."""
    if who and who != bound.name:
        return None, f"flown by {who}, not {bound.name} ({ticks.parent / TRUTH_FILE})"
    try:
        log = TickLog.read(ticks)
    except InputError as exc:
        return None, str(exc)
    sha = str(bound.certificate.get("controller_sha256", ""))
    if log.controller_sha256 and log.controller_sha256 != sha:
        return None, f"flown by {log.controller or 'another controller'} (its log's sha256)"
    if log.controller and log.controller != bound.name and not log.controller_sha256:
        return None, f"flown by {log.controller}, not {bound.name} (its log)"
    if math.isfinite(bound.dt) and (why := log.off_rate(bound.dt)):
        return None, f"not {bound.name}'s ticks: {why}"
    if recorded := recorded_ticks_facts(folder):  # a vehicle's log: prove who flew it
        proof = flown_by(log, bound.folder, float(recorded["mass_kg"]),
                         dict(recorded.get("stamps") or {}))  # fmt: skip
        if not proof.flown:
            return None, f"not flown by {bound.name} ({proof.reason})"
    return log, ""


def recorded_ticks_facts(folder: Path) -> dict[str, Any]:
    """What the ingest of a vehicle's log recorded of its tick log (``results.ticks``:
    ``qsls ingest LOG --mass``, docs/vehicle.md); empty for any other folder."""
    try:
        m = read_manifest(folder)
    except InputError:
        return {}
    facts = (m.get("results") or {}).get("ticks") if m.get("stage") == "ingest" else None
    return dict(facts) if isinstance(facts, dict) and "mass_kg" in facts else {}


def own_log_assumptions(
    flights: Sequence[Path],
    bounds: Sequence[ControllerBound | None],
    training: TrainingData,
    conditions: Sequence[str] | None = None,
    estimators: Sequence[str] | None = None,
) -> tuple[pd.DataFrame | None, list[str]]:
    """Every assumption of ``bounds[i]``'s guarantee (:mod:`qsls.pipeline.evaluate.assumptions`)
    on each flight ``flights[i]`` that keeps the controller's own tick log (``ticks.parquet``
    beside ``flight.parquet``: ``qsls fly`` and ``qsls calibrate`` write it); a flight
    without one is named, with the log it needs. ``bounds[i]`` is the certificate of the
    controller that flew flight ``i`` (its perception condition's, where calibrated per
    condition, ``conditions[i]``, and estimator, ``estimators[i]``: ``''`` where not known);
    ``outside_calibration`` says when that certificate was calibrated under other conditions."""
    rows, missing = [], []
    conds = list(conditions) if conditions is not None else [""] * len(flights)
    ests = list(estimators) if estimators is not None else [""] * len(flights)
    dirs = {b.folder: load_controller_dir(b.folder) for b in bounds if b is not None}
    # each certificate read once: its premise and its calibration record
    read = {f: (premise_of(d), d.certificate.calibration) for f, d in dirs.items()}
    for f, bound, condition, estimator in zip(flights, bounds, conds, ests, strict=True):
        if bound is None:
            continue
        premise, calibration = read[bound.folder]
        if premise is None:
            missing.append(f"--flown-by {bound.name}: its certificate states no premise to check")
            continue
        folder = Path(f) if Path(f).is_dir() else Path(f).parent
        ticks, who = own_log_of(folder)
        if ticks is None:
            missing.append(
                f"{folder}: no {TICKS_FILE} (the controller's own log at its ticks: t, x_*, y_*, "
                f"u_*, r_*, uff_*), so the assumptions of {bound.name}'s guarantee cannot be "
                "checked on it; its premise is checked on the ingested flight"
            )
            continue
        log, why = own_log(folder, ticks, who, bound)
        if log is None:
            missing.append(
                f"{folder}: {why}: the assumptions of {bound.name}'s guarantee are checked on "
                "its own flights only"
            )
            continue
        row = check_assumptions(log, premise, training.distance)
        span = float(log.t[-1] - log.t[0]) if len(log.t) else 0.0
        row["outside_calibration"] = outside_calibration(
            calibration, condition, span, estimator, simulated_conditions(ticks)
        )
        rows.append({"flight": folder.name, "controller": bound.name, "status": bound.status,
                     "crashed": False, **row})  # fmt: skip
    return (pd.DataFrame(rows) if rows else None), list(dict.fromkeys(missing))
