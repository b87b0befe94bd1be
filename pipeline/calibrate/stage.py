"""``qsls calibrate``: a certificate calibrated on flights its design never saw, then validated
on fresh ones (docs/calibration.md).

Each candidate (a robust controller whose design check passed in ``qsls synth``) is read once
(:class:`Candidate`). Then, per candidate and perception condition, two phases:

1. **Calibration**: the candidate flies ``flights`` flights with seeds ``seed, seed + 1, ...``
   (never a design flight's seed), each drawing its conditions from the stated family, and
   with ``range_flights`` the reference moved by random offsets within ``tube``
   (:mod:`qsls.pipeline.calibrate.flights`); or the user's recorded flights are read and
   proved its own; or, with ``source: standin``, the stand-in vehicle flies them and logs
   them as a PX4 vehicle would (output ``standin/``), and they are read as recorded ones.
   Each flight's score and the decision are :mod:`qsls.pipeline.calibrate.core`'s; the
   calibrated certificate is written with its ``calibration`` record and the innovation
   monitor's calibration.
2. **Validation**: fresh seeds (or recorded validation flights), flown by the calibrated
   controller and checked against every assumption of the calibrated premise; the share that
   breaks one, with its Clopper-Pearson interval, beside ``alpha``.

Output (``OUT``): ``<condition>/<controller>/`` (``certificate.yaml`` with its ``calibration``
record and ``controller.npz``: a controller folder every other command reads),
``scores.parquet`` (one row per calibration or range flight: the per-quantity ratios and the
score), ``validation.parquet`` (one row per validation flight: every assumption),
``calibration.json`` (the summary per candidate and condition) and, for simulated flights,
``flights/<name>/ticks.parquet``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from qsls.pipeline.calibrate import core, flights
from qsls.pipeline.calibrate.core import Outcome, Record, Rule, Scores
from qsls.pipeline.calibrate.options import CalibrateOptions
from qsls.pipeline.calibrate.recorded import RecordedFlight, load_all, refuse_design
from qsls.pipeline.calibrate.standin import standin_flights
from qsls.pipeline.calibrate.summary import SUMMARY_FILE, summary_row
from qsls.pipeline.control.artifacts import (
    CERTIFICATE_FILE,
    CONTROLLER_FILE,
    Certificate,
    ControllerDir,
    FlightEvidence,
    load_controller_dir,
)
from qsls.pipeline.control.calibration import Responses
from qsls.pipeline.core.artifacts import (
    StageWriter,
    atomic_write_bytes,
    check_output,
    read_manifest,
)
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.errormodel.model import load_error_model, resolve_model
from qsls.pipeline.evaluate.assumptions import (
    CertifiedPremise,
    FlownLog,
    check_assumptions,
    crashed,
)
from qsls.pipeline.evaluate.certified import expand_controllers, premise_of
from qsls.pipeline.evaluate.conditions import drawn, stated
from qsls.pipeline.evaluate.training import TrainingData, load_training

STAGE = "calibrate"
SCORES_FILE = "scores.parquet"
VALIDATION_FILE = "validation.parquet"


# --------------------------------------------------------------------------- the candidates
@dataclass(frozen=True)
class Candidate:
    """A candidate controller folder, read once: what its calibration needs of it."""

    dir: ControllerDir
    premise: CertifiedPremise | None
    """What its certificate promises (None: no premise to calibrate)."""
    responses: Responses

    @property
    def name(self) -> str:
        return self.dir.name

    @classmethod
    def read(cls, d: ControllerDir) -> Candidate:
        return cls(d, premise_of(d), core.responses(d))


@dataclass(frozen=True)
class Calibrated:
    """One candidate calibrated in one condition: its outcome and its calibrated folder."""

    controller: str
    condition: str
    outcome: Outcome
    dir: ControllerDir


@dataclass(frozen=True)
class CalibrateResult:
    out: Path
    outcomes: tuple[Calibrated, ...]
    validation: pd.DataFrame
    summary_rows: tuple[dict[str, Any], ...]

    def summary(self) -> dict[str, Any]:
        return {"output": self.out.as_posix(), "certificates": len(self.outcomes)}


def candidates(synth_dir: Path, names: Sequence[str] | None) -> list[Candidate]:
    """Robust controllers of ``synth_dir`` whose design check passed (or ``names``), each
    folder read once."""
    by = {f.name: f for f in expand_controllers([synth_dir])}
    if names is not None:
        missing = [n for n in names if n not in by]
        if missing:
            raise InputError(
                f"calibrate: no controller {', '.join(missing)} in {synth_dir} "
                f"(have: {', '.join(sorted(by))})"
            )
        return [Candidate.read(load_controller_dir(by[n])) for n in names]
    dirs = [load_controller_dir(f) for f in by.values()]
    return [Candidate.read(d) for d in dirs if _passed(d.certificate)]


def _passed(c: Certificate) -> bool:
    robust = (c.checks or {}).get("robustness", {}).get("passed")
    return bool(c.robust and c.rho_star is not None and robust)


def fitted_seeds(fit_dir: Path) -> list[int]:
    """The seeds of the simulated flights behind the error model in ``fit_dir``: its inputs
    (ingest folders, and simulate folders whose logged inputs measured ``eps_w``), each
    ingest folder's source (a simulate folder's bag), that simulate manifest's seed. A
    recorded log, or a folder moved since, gives none: give those with ``--design-seeds``."""
    seeds: set[int] = set()

    def manifest(folder: Path) -> dict[str, Any]:
        try:
            return read_manifest(folder)
        except InputError:
            return {}

    def inputs(m: dict[str, Any]) -> list[Path]:
        return [Path(str(i.get("path", ""))) for i in m.get("inputs", []) if isinstance(i, dict)]

    for p in inputs(manifest(fit_dir)):
        m = manifest(p if p.is_dir() else p.parent)
        sims = [m] if m.get("stage") == "simulate" else [manifest(q.parent) for q in inputs(m)]
        for sm in sims:
            seed = (sm.get("options") or {}).get("seed") if sm.get("stage") == "simulate" else None
            if isinstance(seed, int):
                seeds.add(seed)
    return sorted(seeds)


@dataclass(frozen=True)
class _Inputs:
    """What the stage reads once, before anything flies."""

    model_file: Path
    fit_dir: Path
    training: TrainingData
    candidates: list[Candidate]


def _inputs(error_model: Path, synth_dir: Path, options: CalibrateOptions) -> _Inputs:
    model_file, fit_dir = resolve_model(error_model)
    found = candidates(Path(synth_dir), options.controllers)
    if not found:
        raise InputError(
            f"calibrate: {synth_dir} holds no robust controller whose design check passed; "
            "nothing to calibrate (see its certificates' checks)"
        )
    training = load_training(fit_dir, load_error_model(model_file), None)
    return _Inputs(model_file, fit_dir, training, found)


def _with_design_seeds(options: CalibrateOptions, fit_dir: Path) -> CalibrateOptions:
    design = sorted(set(options.design_seeds) | set(fitted_seeds(fit_dir)))
    return options.model_copy(update={"design_seeds": design})


def _premise(c: Candidate, why: str) -> CertifiedPremise:
    if c.premise is None:
        raise InputError(f"calibrate: {c.name} has no premise to calibrate{why}")
    return c.premise


def _write(folder: Path, source: ControllerDir, cert: Certificate) -> ControllerDir:
    """The calibrated controller folder: ``source``'s controller and ``cert``."""
    folder.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(folder / CONTROLLER_FILE, (source.folder / CONTROLLER_FILE).read_bytes())
    atomic_write_bytes(folder / CERTIFICATE_FILE, cert.to_yaml().encode())
    return ControllerDir(folder, source.controller, cert)


def certify(
    c: Candidate,
    folder: Path,
    rows: Sequence[Mapping[str, Any]],
    record: Record,
    logs: Sequence[FlownLog],
    options: CalibrateOptions,
) -> tuple[Outcome, ControllerDir]:
    """Decide on ``c``'s score ``rows`` (its calibration and range flights, in order), write
    the calibrated folder with its record and the monitor's calibration on ``logs`` (the
    calibration flights' tick logs)."""
    premise = _premise(c, "")
    o = core.decide(Scores.of(rows), premise.numbers, c.responses, record.rule)
    cert = core.calibrated_certificate(c.dir.certificate, premise, o, record)
    cert = core.with_monitor(ControllerDir(folder, c.dir.controller, cert), logs, options.monitor)
    return o, _write(folder, c.dir, cert)


@dataclass(frozen=True)
class _Tables:
    """What a calibration's flights gave, for its tables."""

    rows: list[dict[str, Any]]
    """One per calibration or range flight (``scores.parquet``)."""
    vrows: list[dict[str, Any]]
    """One per validation flight (``validation.parquet``)."""
    done: list[Calibrated]


def _finish(
    w: StageWriter, t: _Tables, rule: Rule, recorded: Mapping[str, str] | None
) -> CalibrateResult:
    """Write the tables and the summary (``recorded``: the recorded flights' owners, None for
    simulated flights); the result."""
    scores, validation = pd.DataFrame(t.rows), pd.DataFrame(t.vrows)
    by = None if recorded is not None else scores
    summary = [
        summary_row(r.controller, r.condition, r.outcome, validation, rule, by) for r in t.done
    ]
    w.write_parquet(SCORES_FILE, scores)
    w.write_parquet(VALIDATION_FILE, validation)
    head: dict[str, Any] = {"alpha": rule.alpha, "method": rule.method, "delta": rule.delta}
    if recorded is not None:
        head["source"] = "recorded"
    w.write_json(SUMMARY_FILE, {**head, "certificates": summary})
    w.results.update({"certificates": summary})
    if recorded is not None:
        w.results.update({"flown_by": dict(recorded)})
    return CalibrateResult(w.out, tuple(t.done), validation, tuple(summary))


# --------------------------------------------------------------------------- the stage
def calibrate(
    error_model: Path,
    synth_dir: Path,
    options: CalibrateOptions,
    out: Path,
    *,
    force: bool = False,
    progress: Progress = NULL_PROGRESS,
) -> CalibrateResult:
    """The stage: calibrate and validate every candidate's premise on flights it flew itself
    (module docstring). Recorded ones where ``options`` gives them or the stand-in flies them
    (:attr:`CalibrateOptions.flies_recorded`, :func:`_recorded_phases`, docs/vehicle.md), else
    simulated ones (:func:`_calibration_phase`, :func:`_validation_phase`). Flights that are
    not the user's are flown on seeds no design flight used."""
    if options.flies_recorded:
        _refuse_recorded(options)
    check_output(Path(out), force)
    inp = _inputs(error_model, synth_dir, options)
    if options.flown_here:
        options = _with_design_seeds(options, inp.fit_dir)
        options.seed_lists()
    if not options.flies_recorded:
        for c in inp.candidates:
            _premise(c, " (a nominal or failed controller)")
    rec = options.recorded
    folders = [c.dir.folder for c in inp.candidates]
    inputs = [inp.model_file, *folders, *rec.paths]
    with StageWriter(out, STAGE, options=options, inputs=inputs, force=force) as w:
        if options.flies_recorded:
            t, owners = _recorded_phases(w, inp, options, progress)
            return _finish(w, t, Rule.of_options(options), owners)
        sim = options.sim.model_dump(mode="json")
        sim["duration"] = options.duration
        t = _calibration_phase(w, inp, options, sim, progress)
        _validation_phase(w, t, inp, options, sim, progress)
        return _finish(w, t, Rule.of_options(options), None)


# --------------------------------------------------------------------------- simulated flights
def _conditions(options: CalibrateOptions, sim: dict[str, Any]) -> dict[str, Any]:
    """What the record states of the simulated flights' conditions (the perception added per
    condition)."""
    family = {
        k: v
        for k, v in stated(options.family, sim).items()
        if k != "family" or not options.family.point
    }
    return {
        "estimator": str(getattr(options.sim.vio, "kind", "emulator")),
        "reference": sim["reference"],
        **({"range_tube_m": options.tube} if options.range_flights else {}),
        "duration_s": options.duration,
        "vehicle": sim["vehicle"],
        **family,
    }


def _calibration_phase(
    w: StageWriter, inp: _Inputs, options: CalibrateOptions, sim: dict[str, Any], progress: Progress
) -> _Tables:
    """Fly and score every calibration and range flight; decide and write each candidate's
    calibrated folder."""
    calib_seeds, _ = options.seed_lists()
    by = {c.name: c for c in inp.candidates}
    flyer = flights.Flyer(
        lambda cond, n: by[n].dir.folder, lambda n: by[n].dir.certificate.controller_sha256
    )
    names = list(by)
    todo = flights.jobs("calibration", calib_seeds, names, flyer, options, sim)
    todo += flights.jobs("range", options.range_seeds, names, flyer, options, sim)
    logs = flights.fly_jobs(todo, options, progress, "calibration flights")
    t = _Tables([], [], [])
    evidence: dict[str, FlightEvidence] = {}
    for j, tk in zip(todo, logs, strict=True):
        evidence[j.name] = flights.keep(w, j, tk)
        parts = core.scored(tk, _premise(by[j.controller], ""), inp.training.distance, j.role)
        t.rows.append(
            {
                "flight": j.name,
                "role": j.role,
                "controller": j.controller,
                "condition": j.condition,
                "seed": j.seed,
                "offset_m": float(np.hypot(*j.offset[:2])),
                "crashed": tk.crashed,
                **drawn(options.family, j.sim),
                **parts,
            }
        )
    flown = {j.name: tk for j, tk in zip(todo, logs, strict=True)}
    conditions = _conditions(options, sim)
    seen = set(calib_seeds) | set(options.range_seeds) | set(options.seed_lists()[1])
    for cond in options.conditions:
        for c in inp.candidates:
            mine = [r for r in t.rows if (r["condition"], r["controller"]) == (cond, c.name)]
            cal = [r["flight"] for r in mine if r["role"] == "calibration"]
            ranged = [r["flight"] for r in mine if r["role"] == "range"]
            record = Record(
                Rule.of_options(options),
                {**conditions, "perception": cond},
                options.duration,
                tuple(calib_seeds),
                tuple(options.design_seeds),
                tuple(sorted(seen)) if calib_seeds else (),
                tuple(r for r in mine if r["role"] == "calibration"),
                evidence=tuple(evidence[n] for n in (*cal, *ranged)),
            )
            o, d = certify(
                c, w.path(f"{cond}/{c.name}"), mine, record, [flown[n] for n in cal], options
            )
            t.done.append(Calibrated(c.name, cond, o, d))
    return t


def _validation_phase(
    w: StageWriter,
    t: _Tables,
    inp: _Inputs,
    options: CalibrateOptions,
    sim: dict[str, Any],
    progress: Progress,
) -> None:
    """Fly the validation flights with each calibrated controller, check them against its
    premise, and add their tick logs to its record."""
    _, valid_seeds = options.seed_lists()
    by = {(r.condition, r.controller): r for r in t.done}
    flyer = flights.Flyer(
        lambda cond, n: w.path(f"{cond}/{n}"),
        lambda n: next(r.dir.certificate.controller_sha256 for r in t.done if r.controller == n),
    )
    todo = flights.jobs(
        "validation", valid_seeds, [c.name for c in inp.candidates], flyer, options, sim
    )
    if not todo:
        return
    logs = flights.fly_jobs(todo, options, progress, "validation flights")
    premise = {k: premise_of(r.dir) for k, r in by.items()}
    evidence: dict[tuple[str, str], list[Any]] = {k: [] for k in by}
    for j, tk in zip(todo, logs, strict=True):
        evidence[(j.condition, j.controller)].append(flights.keep(w, j, tk))
        c = premise[(j.condition, j.controller)]
        if c is None:
            continue
        row = check_assumptions(tk, c, inp.training.distance)
        if tk.crashed:
            row = crashed(row, float(tk.t[-1]), tk.crash_reason)
        t.vrows.append(
            {
                "flight": j.name,
                "controller": j.controller,
                "condition": j.condition,
                "seed": j.seed,
                **row,
            }
        )
    for k, r in by.items():  # the validation flights' tick logs join the record
        cert = core.with_evidence(r.dir.certificate, evidence[k])
        if cert is not r.dir.certificate:
            atomic_write_bytes(r.dir.folder / CERTIFICATE_FILE, cert.to_yaml().encode())


# --------------------------------------------------------------------------- recorded flights
def _refuse_recorded(options: CalibrateOptions) -> None:
    """Recorded options the stage cannot calibrate on, refused before anything is read."""
    if options.recorded.given and not options.recorded.calibration:
        raise InputError(
            "calibrate: recorded range or validation flights need recorded calibration "
            "flights (--recorded FOLDER, repeated or comma-separated)"
        )
    if len(options.conditions) > 1:
        raise InputError(
            "calibrate: recorded flights are flown under the conditions they met: give one "
            "condition (--conditions NAME) to name them"
        )


def _recorded_phases(
    w: StageWriter, inp: _Inputs, options: CalibrateOptions, progress: Progress
) -> tuple[_Tables, dict[str, str]]:
    """Prove, score, calibrate and validate every candidate on the recorded flights
    (docs/vehicle.md); with ``options.source == "standin"`` and none given, the stand-in
    vehicle flies them first (:mod:`qsls.pipeline.calibrate.standin`). Each flight must be the
    candidate's own: replayed through its taps and gate it gives the logged commands. The
    record lists each calibration flight's log sha256 (``calibration.logs``) in place of
    seeds; the tick logs stay in their ingest folders. Returns the tables and each flight's
    owner."""
    standin = options.flown_here
    rec = options.recorded
    folders = [c.dir.folder for c in inp.candidates]
    if standin:
        dt = min(c.dir.controller.dt for c in inp.candidates)
        height = float(options.sim.reference.height)
        rec = standin_flights(
            folders,
            options,
            w.path("standin"),
            dt,
            lambda s: flights.offsets(s, options.tube, height),
            progress,
        )
    given = load_all(rec.by_role)
    refuse_design(given, inp.fit_dir)
    owners = flights.assign(given, folders)
    t = _Tables([], [], [])
    progress.start("recorded flights", total=len(given))
    for c in inp.candidates:
        mine = [f for f in given if owners[f.name] == c.name]
        if any(f.role == "calibration" for f in mine):
            _recorded_one(w, t, c, mine, options, inp.training, standin)
            progress.advance(len(mine))
    progress.finish()
    if not t.done:
        raise InputError(
            "calibrate: none of the candidates flew a calibration flight among those given"
        )
    return t, owners


def _recorded_one(
    w: StageWriter,
    t: _Tables,
    c: Candidate,
    given: list[RecordedFlight],
    options: CalibrateOptions,
    training: TrainingData,
    standin: bool,
) -> None:
    """One candidate on its own recorded flights: scores, the decision, the calibrated folder,
    the validation."""
    condition = options.conditions[0]
    premise = _premise(c, "")
    flights.check_dt(given, c.dir.folder, float(c.dir.controller.dt))
    rows: list[dict[str, Any]] = [
        {
            "flight": f.name,
            "role": f.role,
            "controller": c.name,
            "condition": condition,
            "log_sha256": f.log_sha256,
            "crashed": False,
            **core.scored(f.log, premise, training.distance, f.role),
        }
        for f in given
        if f.role != "validation"
    ]
    calib = [f for f in given if f.role == "calibration"]
    estimator = str(options.sim.vio.kind) if standin else ""
    conditions = flights.recorded_conditions(
        [f for f in given if f.role != "validation"], condition, estimator
    )
    root = w.path(condition).parent  # the output: a stand-in's tick logs are named inside it
    order = {"calibration": 0, "range": 1, "validation": 2}
    record = Record(
        Rule.of_options(options),
        conditions,
        float(conditions["duration_s"]),
        design_seeds=tuple(options.design_seeds),
        parts=tuple(r for r in rows if r["role"] == "calibration"),
        logs=tuple(f.log_sha256 for f in calib),
        evidence=tuple(
            flights.recorded_evidence(f, root) for f in sorted(given, key=lambda f: order[f.role])
        ),
    )
    o, d = certify(
        c, w.path(f"{condition}/{c.name}"), rows, record, [f.log for f in calib], options
    )
    t.rows.extend(rows)
    t.done.append(Calibrated(c.name, condition, o, d))
    checked = premise_of(d)
    if checked is None:
        return
    t.vrows.extend(
        {
            "flight": f.name,
            "controller": c.name,
            "condition": condition,
            "log_sha256": f.log_sha256,
            **check_assumptions(f.log, checked, training.distance),
        }
        for f in given
        if f.role == "validation"
    )
