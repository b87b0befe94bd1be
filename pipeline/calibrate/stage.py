"""``qsls calibrate``: a certificate calibrated on flights its design never saw, then validated
on fresh ones (docs/calibration.md).

For each candidate (a robust controller whose design check passed in ``qsls synth``) and each
perception condition:

1. **Calibration flights**: the candidate itself flies ``flights`` flights with seeds
   ``seed, seed + 1, ...`` (never a design flight's seed) under the stated conditions (the
   design's vehicle, reference and estimator). With ``range_flights``, it also flies the
   reference moved by random offsets within ``tube``: those flights reach distances toward
   ``rho*`` and are scored on every premise quantity but the reference's distance
   (:func:`range_score`). Each flight keeps the controller's own tick log (``ticks.parquet``: ``t``,
   ``x_*``, ``y_*``, ``u_*``, ``r_*``, ``uff_*``) and gets its score ``lambda_f``
   (:func:`score_flight`, :mod:`qsls.pipeline.control.calibration`).
2. **The calibrated certificate**: ``lambda_hat`` from the scores (split conformal or PAC), the
   premise inflated by it, the robustness condition re-checked on the fixed taps, the tested
   range (the largest ``dist(x_k)`` the calibration flights reached) against the inflated
   ``rho*``, and the tolerance of each premise quantity. ``status: certified`` needs the
   condition, ``flights >= 19``, ``alpha <= 0.1`` and the tested range to reach ``rho*``
   (else ``extrapolated``); anything else is ``relaxed``, with the reason.
3. **Validation flights**: fresh seeds, flown by the calibrated controller and checked against
   every assumption of the calibrated premise; the share that breaks one, with its
   Clopper-Pearson interval, beside ``alpha``.

Output (``OUT``): ``<condition>/<controller>/`` (``certificate.yaml`` with its ``calibration``
record and ``controller.npz``: a controller folder every other command reads),
``scores.parquet`` (one row per calibration flight: the per-quantity ratios and the score),
``validation.parquet`` (one row per validation flight: every assumption),
``calibration.json`` (the summary per candidate and condition) and ``flights/<name>/ticks.parquet``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from qsls.pipeline.calibrate.broken import broken_premise
from qsls.pipeline.calibrate.options import CalibrateOptions as CalibrateOptions
from qsls.pipeline.control import calibration as cal
from qsls.pipeline.control import guarantee
from qsls.pipeline.control.artifacts import (
    CERTIFICATE_FILE,
    CONTROLLER_FILE,
    Calibration,
    Certificate,
    FlightEvidence,
    calibration_problems,
    load_controller_dir,
)
from qsls.pipeline.control.guarantee import (
    PremiseNumbers,
    measured_channels,
    outlier_channels,
    system_norms,
)
from qsls.pipeline.control.innovation import monitor_calibration
from qsls.pipeline.control.monitor import hover_input, sound_innovation_of
from qsls.pipeline.control.status import CERTIFIED, EXTRAPOLATED, RELAXED
from qsls.pipeline.core.artifacts import (
    StageWriter,
    atomic_write_bytes,
    check_output,
    read_manifest,
    sha256_file,
)
from qsls.pipeline.core.config import merge
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.plant import bias_directions
from qsls.pipeline.core.pools import pool_size, run_tasks
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.errormodel.model import load_error_model, resolve_model
from qsls.pipeline.evaluate.assumptions import (
    CertifiedPremise,
    FlownLog,
    check_assumptions,
    crashed,
    signals,
)
from qsls.pipeline.evaluate.certified import certified_premise, expand_controllers
from qsls.pipeline.evaluate.conditions import draw, drawn, stated
from qsls.pipeline.evaluate.training import load_training
from qsls.pipeline.evaluate.verdict import promise
from qsls.pipeline.sim.closedloop import fly
from qsls.pipeline.sim.options import SimOptions
from qsls.pipeline.sim.ticks import TICKS_FILE as TICKS_FILE
from qsls.pipeline.sim.ticks import TickLog as TickLog
from qsls.pipeline.sim.ticks import tick_log

STAGE = "calibrate"
SCORES_FILE = "scores.parquet"
VALIDATION_FILE = "validation.parquet"
SUMMARY_FILE = "calibration.json"


# --------------------------------------------------------------------------- flights
@dataclass(frozen=True)
class Job:
    """One flight of a candidate."""

    name: str
    controller: str
    folder: str
    condition: str
    seed: int
    role: str
    """``calibration`` (its score enters the quantile), ``range`` (its reference moved within
    the tube: it tests the premise out to ``rho*``) or ``validation`` (checked, never scored)."""
    sim: dict[str, Any]
    """The flight's simulation options (the run's, its condition's and its family draw)."""
    offset: tuple[float, float, float]
    """The reference's offset (a range flight's; zeros otherwise)."""


def fly_job(job: Job) -> TickLog:
    """Fly ``job`` (no bag: the tick log is what the scores read)."""
    ref = dict(job.sim.get("reference") or {})
    cx, cy = ref.get("center", (0.0, 0.0))
    over: dict[str, Any] = {
        "seed": job.seed,
        "controller": {"kind": job.folder},
        "vio": {"perception": job.condition},
    }
    if any(job.offset):
        over["reference"] = {
            "center": [float(cx) + job.offset[0], float(cy) + job.offset[1]],
            "height": float(ref.get("height", 1.0)) + job.offset[2],
        }
    opts = SimOptions.model_validate(merge(job.sim, over))
    folder = Path(job.folder)
    sha = (
        Certificate.load(folder).controller_sha256 if (folder / CERTIFICATE_FILE).is_file() else ""
    )
    return tick_log(fly(opts), sha)


# --------------------------------------------------------------------------- scores
def score_flight(
    log: FlownLog, c: CertifiedPremise, distance: Callable[[np.ndarray], np.ndarray]
) -> dict[str, float]:
    """The flight's ratio for each premise quantity and its score ``lambda_f``
    (:mod:`qsls.pipeline.control.calibration`), with what the flight reached:

    - ``dense``: ``max |d_k|_e / (eps + S dist(x_k))`` over the samples within ``r``;
    - ``disturbance``: ``max ||H^-1 w_k||_inf / eps_w``; with a bias term the smallest
      inflation of ``(eps_w, eps_b)`` that holds (``split_bias``: one constant ``beta``);
    - ``reference``: ``max dist(x_ref,k) / Delta``;
    - ``outliers``: the largest outlier count in ``T`` consecutive ticks over ``m`` (inf when
      an outlier exceeds ``eps_o``, which the gate fixes and no inflation moves);
    - ``reached``: the largest ``dist(x_k)`` within ``r``, where the flight tested the dense
      premise (beyond ``r`` the premise claims nothing).
    """
    sig = signals(log, c, distance)
    dense, mag, dist, w, counts = sig.dense, sig.mag, sig.dist, sig.w, sig.counts
    inside = dist <= c.numbers.radius
    allowed = guarantee.premise_bound(c.numbers.eps, c.numbers.S, dist)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(dense > 0, dense / allowed, 0.0)
    ref_max = float(distance(log.ref).max())
    parts = {
        "dense": float(rel[inside].max()) if inside.any() else 0.0,
        "disturbance": sig.split.ratio,
        "reference": cal.ratio(ref_max, c.numbers.delta),
        "outliers": math.inf
        if mag.max() > c.numbers.eps_o
        else cal.ratio(float(counts.max()), c.numbers.m),
    }
    # reached: where the dense premise was scored (within r; a flight that went further passed
    # through every distance up to r on the way)
    reached = float(dist[inside].max()) if inside.any() else 0.0
    return {**parts, "score": cal.flight_score(parts), "reached": reached,
            "w_max": float(w.max()) if len(w) else 0.0, "window_max": float(counts.max()),
            "ref_max": ref_max, "outlier_max": float(mag.max()),
            "bias": float(np.abs(sig.split.beta).max())}  # fmt: skip


def range_score(parts: dict[str, float]) -> float:
    """A range flight's score: ``max(dense, disturbance, outliers)``. Its reference is offset on
    purpose, so the reference term (``dist(x_ref) / Delta``) is left out; the disturbance stays
    in: ``||H^-1 w_k|| <= eps_w`` is assumed at every state out to ``rho*``, and a range flight
    is where the states far from the training data are (docs/calibration.md, Tested range)."""
    return max(parts["dense"], parts["disturbance"], parts["outliers"])


def offsets(seed: int, tube: float, height: float = 1.0) -> tuple[float, float, float]:
    """The reference offset of flight ``seed`` in a tube of radius ``tube``: uniform in the
    horizontal disc of radius ``tube``, the height uniform within ``tube / 2`` but never
    below :data:`MIN_HEIGHT` (its own seeded stream)."""
    if tube <= 0:
        return (0.0, 0.0, 0.0)
    rng = np.random.default_rng([seed, 7919])
    r = tube * math.sqrt(rng.uniform())
    th = rng.uniform(0, 2 * math.pi)
    dz = rng.uniform(max(-tube / 2, MIN_HEIGHT - height), tube / 2)
    return (r * math.cos(th), r * math.sin(th), dz)


MIN_HEIGHT = 0.6
"""Lowest reference height of a range flight (m): lower, the circle's ground effect and the
floor-crash rule decide the flight, not perception."""


# --------------------------------------------------------------------------- the certificate
def taps_of(folder: Path) -> cal.Responses:
    """What the condition needs of the candidate's taps, in its certificate's weights."""
    d = load_controller_dir(folder)
    c = d.certificate
    p = c.premise
    taps, model = d.controller.taps, d.controller.model
    extra = model.nx - 6  # the attitude plant's states: unweighted, error-free
    sx = (*(p.state_scale if p is not None else (1.0,) * 6), *(0.0,) * extra)
    se = (*(p.error_scale if p is not None else (1.0,) * 6), *(1.0,) * extra)
    measured = measured_channels(c.measure)
    outlier = outlier_channels(c.measure, 1)  # G_m is recomputed per m
    phi_xx_h = taps.Phi_xx @ model.H
    dirs = bias_directions(model)
    norms = system_norms(
        taps.Phi_xy, phi_xx_h, state_scale=sx, error_scale=se, measured=measured, bias_dirs=dirs
    )
    return cal.Responses(taps.Phi_xy, phi_xx_h, sx, se, measured, outlier, norms, dirs)


@dataclass(frozen=True)
class Decision:
    """What :func:`decide` finds of a candidate's scores (module docstring)."""

    status: str
    reason: str
    lambda_hat: float
    rank: int
    check: cal.Check | None
    """The condition under the premise inflated by ``lambda_hat`` (None: no finite one)."""
    tested_range: float
    tolerances: dict[str, float]


@dataclass(frozen=True)
class Outcome(Decision):
    """One candidate's calibration in one condition: its :class:`Decision` on its scores."""

    controller: str = ""
    condition: str = ""
    scores: list[float] = field(default_factory=list)

    @classmethod
    def of(cls, controller: str, condition: str, d: Decision, scores: Sequence[float]) -> Outcome:
        return cls(**vars(d), controller=controller, condition=condition, scores=list(scores))


def decide(
    scores: Sequence[float],
    reached: Sequence[float],
    nominal: PremiseNumbers,
    taps: cal.Responses,
    options: CalibrateOptions,
    crashed: int = 0,
    range_scores: Sequence[float] = (),
    broken: Sequence[Mapping[str, Any]] = (),
) -> Decision:
    """The candidate's :class:`Decision` (module docstring); ``reached`` covers the calibration and the range flights, ``range_scores`` are
    the range flights' scores (:func:`range_score`) (their quantile can only raise ``lambda_hat``);
    ``broken``: the score rows of the flights whose score is inf (the refusal names their
    quantities, :func:`~qsls.pipeline.calibrate.broken.broken_premise`)."""
    n = len(scores)
    rank = cal.calibration_rank(n, options.alpha, options.method, options.delta)
    lam = cal.calibrated_quantile(scores, options.alpha, options.method, options.delta)
    if len(range_scores):
        lam = max(
            lam, cal.calibrated_quantile(range_scores, options.alpha, options.method, options.delta)
        )
    tested = float(max(reached, default=0.0))
    if not math.isfinite(lam):
        need = cal.smallest_flights(options.alpha, options.method, options.delta)
        short = [
            f"{k} {what} flights"
            for k, what in ((n, "calibration"), (len(range_scores), "range"))
            if k and cal.calibration_rank(k, options.alpha, options.method, options.delta) > k
        ]
        why = (
            f"{' and '.join(short)} cannot support alpha {options.alpha:g} ({options.method} "
            f"needs {need} for any calibrated premise, certified needs {cal.MIN_FLIGHTS}: "
            f"--flights {max(need, cal.MIN_FLIGHTS)})"
            if short
            else broken_premise(broken, nominal)
        )
        return Decision(RELAXED, why, lam, rank, None, tested, {})
    inflated = cal.inflate(nominal, lam)
    chk = cal.check(inflated, taps)
    tol: dict[str, float] = (
        {q: cal.tolerance(inflated, taps, q) for q in cal.QUANTITIES} if chk.holds else {}
    )
    if chk.holds:  # a quantity stated as 0 has an infinite factor: its largest value instead
        tol |= {
            f"{q}_max": cal.largest_value(inflated, taps, q)
            for q in cal.QUANTITIES
            if q != "m" and float(getattr(inflated, q)) == 0.0
        }
    reasons = []
    if crashed:
        reasons.append(f"{crashed} calibration flight(s) crashed")
    if not chk.holds:
        reasons.append(
            f"the taps fail the robustness condition under the premise inflated by "
            f"lambda_hat {lam:.3g} (lhs {chk.guarantee.robustness_lhs:.3g}, rho* "
            f"{chk.guarantee.rho_star:.3g} against r {nominal.radius:g}"
            + (f", rho_v {chk.rho_v:.3g} against the gate {nominal.gate:g})" if chk.rho_v is not None else ")")
        )  # fmt: skip
    if n < cal.MIN_FLIGHTS:
        reasons.append(f"{n} calibration flights (certified needs {cal.MIN_FLIGHTS})")
    if options.alpha > cal.MAX_ALPHA:
        reasons.append(f"alpha {options.alpha:g} > {cal.MAX_ALPHA:g}")
    if reasons:
        return Decision(RELAXED, "; ".join(reasons), lam, rank, chk, tested, tol)
    rho = chk.guarantee.rho_star
    if tested < rho:
        why = (f"the flights reached dist {tested:.3g} from the training states while the "
               f"certificate uses the premise out to rho* {rho:.3g}: add range flights over a "
               "tube that reaches it (--range-flights N --tube R; calibrate.range_flights, "
               "calibrate.tube in a config)")  # fmt: skip
        return Decision(EXTRAPOLATED, why, lam, rank, chk, tested, tol)
    return Decision(CERTIFIED, "", lam, rank, chk, tested, tol)


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


def calibrated_checks(
    design: dict[str, dict[str, Any]] | None, chk: cal.Check
) -> dict[str, dict[str, Any]]:
    """The certificate's checks with the robustness condition (and the gate) read under the
    calibrated premise, as the calibrated status is; each keeps its design value beside."""
    out = {k: dict(v) for k, v in (design or {}).items()}
    g = chk.guarantee
    if "robustness" in out:
        out["robustness"] |= {
            "design_value": out["robustness"].get("value"), "value": g.robustness_lhs,
            "passed": bool(chk.holds),
        }  # fmt: skip
    if "gate" in out and chk.rho_v is not None:
        out["gate"] |= {
            "design_value": out["gate"].get("value"), "value": chk.rho_v,
            "passed": bool(chk.rho_v <= float(out["gate"]["limit"]) * (1 + 1e-7)),
        }  # fmt: skip
    return out


def _evidence(options: CalibrateOptions, seeds: Sequence[int]) -> set[int]:
    """Every seed a simulated calibration flew: calibration, range and validation (none for
    recorded flights, whose ``seeds`` are empty)."""
    if not seeds:
        return set()
    return {*seeds, *options.range_seeds, *options.seed_lists()[1]}


def calibrated_certificate(
    folder: Path,
    out: Path,
    o: Outcome,
    options: CalibrateOptions,
    seeds: Sequence[int],
    score_rows: Sequence[dict[str, float]],
    conditions: dict[str, Any],
    range_scores: Sequence[float] = (),
    *,
    logs: Sequence[str] = (),
    duration: float | None = None,
    evidence: Sequence[FlightEvidence] = (),
) -> Path:
    """Write ``out`` (a controller folder): the candidate's controller and its certificate with
    the inflated premise's numbers and the ``calibration`` record."""
    cert = Certificate.load(folder)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out / CONTROLLER_FILE, (folder / CONTROLLER_FILE).read_bytes())
    record = Calibration(
        flights=len(o.scores), alpha=options.alpha,
        confidence=1.0 - options.delta if options.method == "pac" else None,
        method=options.method, conditions=conditions,
        duration_s=options.duration if duration is None else duration,
        seeds=list(seeds), design_seeds=list(options.design_seeds),
        evidence_seeds=sorted(_evidence(options, seeds)),
        scores=[float(s) for s in o.scores], lambda_hat=o.lambda_hat,
        rank=o.rank, tested_range=o.tested_range,
        nominal={"eps_e": cert.eps_e, "S": cert.S, "eps_w": cert.eps_w, "delta": cert.delta,
                 "m": float(cert.m), "rho_star": cert.rho_star, "eps_b": cert.eps_b},
        parts={k: float(max((r[k] for r in score_rows), default=0.0)) for k in cal.SCORED},
        tolerances=o.tolerances, holds=bool(o.check is not None and o.check.holds),
        range_flights=len(range_scores), range_scores=[float(v) for v in range_scores],
        logs=list(logs), evidence=list(evidence),
    )  # fmt: skip
    update: dict[str, Any] = {"status": o.status, "status_reason": o.reason or None,
                              "calibration": record, "tested_range": o.tested_range}  # fmt: skip
    if o.check is not None:
        p, g = o.check.premise, o.check.guarantee
        update |= {
            "eps_e": p.eps, "S": p.S, "eps_w": p.eps_w, "delta": p.delta, "m": p.m,
            "eps_b": p.eps_b, "robustness_lhs": g.robustness_lhs, "margin": g.margin, "a": g.a,
            "rho_star": g.rho_star, "gamma": g.dense_bound,
            # the paper's comparison R0 / (1 - S N) under the calibrated premise: R0 is its
            # error bound (the design's R0 was the design premise's)
            "R0": p.eps if p.R0 is None else p.R0, "gamma_strict": g.gamma_strict,
            "s_times_norm_phi_xy": g.s_times_n, "G_m": o.check.G_m,
            "rho_v": o.check.rho_v if o.check.rho_v is not None else cert.rho_v,
            "checks": calibrated_checks(cert.checks, o.check),
        }  # fmt: skip
    new = cert.model_copy(update=update)
    new = new.model_copy(update={"promise": promise(new.model_dump())})
    Certificate.model_validate(new.model_dump())  # the record must read back
    if new.status == CERTIFIED and (why := calibration_problems(new)):
        raise RuntimeError(f"{out}: a certified record its readers would refuse: {why}")
    atomic_write_bytes(out / CERTIFICATE_FILE, new.to_yaml().encode())
    return out


def record_monitor(folder: Path, logs: Sequence[FlownLog], options: CalibrateOptions) -> None:
    """The innovation monitor's calibration in ``folder``'s record
    (docs/monitor.md#the-calibrated-mode): each calibration flight's statistic (``logs``, in the order of the scores) under the
    calibrated certificate's sound monitor, their conformal quantile at the option's
    false-trip rate, and the mode (:func:`qsls.pipeline.control.innovation.monitor_calibration`);
    nothing where that monitor is off."""
    d = load_controller_dir(folder)
    cert, spec = d.certificate, sound_innovation_of(d)
    if cert.calibration is None or not spec.active:
        return
    mon = options.monitor
    rec = monitor_calibration(spec, logs, hover_input(d), cert.gate, mon.mode, mon.false_trip_rate)
    record = cert.calibration.model_copy(update={"monitor": rec})
    new = cert.model_copy(update={"calibration": record})
    atomic_write_bytes(folder / CERTIFICATE_FILE, new.to_yaml().encode())


# --------------------------------------------------------------------------- the stage
@dataclass(frozen=True)
class CalibrateResult:
    out: Path
    outcomes: tuple[Outcome, ...]
    validation: pd.DataFrame
    summary_rows: tuple[dict[str, Any], ...]

    def summary(self) -> dict[str, Any]:
        return {"output": self.out.as_posix(), "certificates": len(self.outcomes)}


def candidates(synth_dir: Path, names: Sequence[str] | None) -> list[Path]:
    """Robust controllers of ``synth_dir`` whose design check passed (or ``names``)."""
    folders = expand_controllers([synth_dir])
    by = {f.name: f for f in folders}
    if names is not None:
        missing = [n for n in names if n not in by]
        if missing:
            raise InputError(
                f"calibrate: no controller {', '.join(missing)} in {synth_dir} "
                f"(have: {', '.join(sorted(by))})"
            )
        return [by[n] for n in names]
    out = []
    for f in folders:
        c = Certificate.load(f)
        if (
            c.robust
            and c.rho_star is not None
            and (c.checks or {}).get("robustness", {}).get("passed")
        ):
            out.append(f)
    return out


def calibrate(
    error_model: Path,
    synth_dir: Path,
    options: CalibrateOptions,
    out: Path,
    *,
    force: bool = False,
    progress: Progress = NULL_PROGRESS,
) -> CalibrateResult:
    """Fly, score, calibrate and validate every candidate (module docstring)."""

    check_output(Path(out), force)
    model_file, fit_dir = resolve_model(error_model)
    design = sorted(set(options.design_seeds) | set(fitted_seeds(fit_dir)))
    options = options.model_copy(update={"design_seeds": design})
    calib_seeds, valid_seeds = options.seed_lists()
    model = load_error_model(model_file)
    training = load_training(fit_dir, model, None)
    folders = candidates(Path(synth_dir), options.controllers)
    if not folders:
        raise InputError(
            f"calibrate: {synth_dir} holds no robust controller whose design check passed; "
            "nothing to calibrate (see its certificates' checks)"
        )
    premises = {f.name: certified_premise(f) for f in folders}
    for name, p in premises.items():
        if p is None:
            raise InputError(
                f"calibrate: {name} has no premise to calibrate (a nominal or failed controller)"
            )
    sim = options.sim.model_dump(mode="json")
    sim["duration"] = options.duration
    height = float(options.sim.reference.height)
    workers = pool_size(options.jobs)

    def fly_all(jobs: list[Job]) -> list[TickLog]:
        return run_tasks(
            [(fly_job, j) for j in jobs], min(workers, len(jobs)), lambda i: progress.advance(),
            scheduler=options.scheduler, note=progress.note, worker_timeout=options.wait_workers,
            what="calibration",
        )  # fmt: skip

    conditions_of = {
        "estimator": str(getattr(options.sim.vio, "kind", "emulator")), "reference": sim["reference"],
        **({"range_tube_m": options.tube} if options.range_flights else {}),
        "duration_s": options.duration, "vehicle": sim["vehicle"],
        **{k: v for k, v in stated(options.family, sim).items()
           if k != "family" or not options.family.point},
    }  # fmt: skip

    with StageWriter(out, STAGE, options=options, inputs=[model_file, *folders], force=force) as w:

        def jobs_for(
            role: str, seeds: Sequence[int], folder_of: Callable[[str, str], Path]
        ) -> list[Job]:
            return [
                Job(name=f"{role}_{cond}_{f.name}_s{s}", controller=f.name,
                    folder=str(folder_of(cond, f.name).resolve()), condition=cond, seed=s,
                    role=role, sim=merge(sim, draw(options.family, s, sim)),
                    offset=(offsets(s, options.tube, height) if role == "range"
                            else (0.0, 0.0, 0.0)))
                for cond in options.conditions for f in folders for s in seeds
            ]  # fmt: skip

        by_name = {f.name: f for f in folders}
        cjobs = jobs_for("calibration", calib_seeds, lambda cond, n: by_name[n])
        cjobs += jobs_for("range", options.range_seeds, lambda cond, n: by_name[n])
        progress.start("calibration flights", total=len(cjobs))
        ticks = fly_all(cjobs)
        progress.finish()
        rows = []
        evidence: dict[str, FlightEvidence] = {}
        for j, tk in zip(cjobs, ticks, strict=True):
            evidence[j.name] = _kept(w, j, tk)
            parts = score_flight(tk, premises[j.controller], training.distance)
            if j.role == "range":  # the offset is the point: every part but the reference's
                parts["score"] = range_score(parts)
            rows.append({"flight": j.name, "role": j.role, "controller": j.controller,
                         "condition": j.condition, "seed": j.seed,
                         "offset_m": float(np.hypot(*j.offset[:2])), "crashed": tk.crashed,
                         **drawn(options.family, j.sim), **parts})  # fmt: skip
        scores = pd.DataFrame(rows)
        outcomes = []
        for cond in options.conditions:
            for f in folders:
                mine = scores[(scores["condition"] == cond) & (scores["controller"] == f.name)]
                sel = mine[mine["role"] == "calibration"]
                ranged = mine[mine["role"] == "range"]
                s = sel["score"].to_list()
                nominal = premises[f.name].numbers
                decision = decide(
                    s,
                    mine["reached"].to_list(),
                    nominal,
                    taps_of(f),
                    options,
                    crashed=int(mine["crashed"].sum()),
                    range_scores=ranged["score"].to_list(),
                    broken=mine[np.isinf(mine["score"])].to_dict(orient="records"),
                )
                o = Outcome.of(f.name, cond, decision, s)
                outcomes.append(o)
                calibrated_certificate(
                    f,
                    w.path(f"{cond}/{f.name}"),
                    o,
                    options,
                    calib_seeds,
                    sel.to_dict(orient="records"),
                    {**conditions_of, "perception": cond},
                    ranged["score"].to_list(),
                    evidence=[evidence[n] for n in (*sel["flight"], *ranged["flight"])],
                )
                flown = {j.name: tk for j, tk in zip(cjobs, ticks, strict=True)}
                record_monitor(w.path(f"{cond}/{f.name}"), [flown[n] for n in sel["flight"]],
                               options)  # fmt: skip
        vjobs = jobs_for("validation", valid_seeds, lambda cond, n: w.path(f"{cond}/{n}"))
        vrows = []
        if vjobs:
            progress.start("validation flights", total=len(vjobs))
            vticks = fly_all(vjobs)
            progress.finish()
            cal_premise = {(o.condition, o.controller): certified_premise(w.path(f"{o.condition}/{o.controller}"))
                           for o in outcomes}  # fmt: skip
            for j, tk in zip(vjobs, vticks, strict=True):
                evidence[j.name] = _kept(w, j, tk)
                c = cal_premise[(j.condition, j.controller)]
                if c is None:
                    continue
                row = check_assumptions(tk, c, training.distance)
                if tk.crashed:
                    row = crashed(row, float(tk.t[-1]), tk.crash_reason)
                vrows.append({"flight": j.name, "controller": j.controller, "condition": j.condition,
                              "seed": j.seed, **row})  # fmt: skip
            for o in outcomes:  # the validation flights' tick logs join the record
                _add_evidence(w.path(f"{o.condition}/{o.controller}"),
                              [evidence[j.name] for j in vjobs
                               if (j.condition, j.controller) == (o.condition, o.controller)])  # fmt: skip
        validation = pd.DataFrame(vrows)
        summary = [summary_row(o, validation, options, scores) for o in outcomes]
        w.write_parquet(SCORES_FILE, scores)
        w.write_parquet(VALIDATION_FILE, validation)
        w.write_json(SUMMARY_FILE, {"alpha": options.alpha, "method": options.method,
                                    "delta": options.delta, "certificates": summary})  # fmt: skip
        w.results.update({"certificates": summary})
    return CalibrateResult(Path(out), tuple(outcomes), validation, tuple(summary))


PERCEPTION_ATTR = "perception"
"""The perception condition a calibration flight flew, kept in its tick log's metadata (under
the log's sha256, so ``qsls verify`` reads the condition from the evidence: docs/verify.md)."""


def _kept(w: StageWriter, j: Job, tk: TickLog) -> FlightEvidence:
    """Write ``j``'s tick log (``flights/<name>/ticks.parquet``) and name it with its sha256."""
    df = tk.frame()
    df.attrs[PERCEPTION_ATTR] = j.condition
    name = f"flights/{j.name}/{TICKS_FILE}"
    sha = sha256_file(w.write_parquet(name, df))
    role = (
        "range" if j.role == "range" else "validation" if j.role == "validation" else "calibration"
    )
    return FlightEvidence(flight=j.name, role=role, ticks=name, sha256=sha, seed=j.seed)


def _add_evidence(folder: Path, more: Sequence[FlightEvidence]) -> None:
    """Append ``more`` (the validation flights' tick logs) to ``folder``'s calibration record."""
    cert = Certificate.load(folder)
    if cert.calibration is None or not more:
        return
    record = cert.calibration.model_copy(update={"evidence": [*cert.calibration.evidence, *more]})
    atomic_write_bytes(folder / CERTIFICATE_FILE,
                       cert.model_copy(update={"calibration": record}).to_yaml().encode())  # fmt: skip


def summary_row(
    o: Outcome,
    validation: pd.DataFrame,
    options: CalibrateOptions,
    scores: pd.DataFrame | None = None,
) -> dict[str, Any]:
    """One candidate's line: its calibration, which premise quantity set ``lambda_hat``
    (:func:`qsls.pipeline.control.calibration.set_by`, from its flights' ``scores``) and its
    validation share against ``alpha``."""
    g = o.check.guarantee if o.check is not None else None
    mine = (scores[(scores["controller"] == o.controller) & (scores["condition"] == o.condition)]
            if scores is not None and len(scores) else pd.DataFrame())  # fmt: skip
    row: dict[str, Any] = {
        "controller": o.controller, "condition": o.condition, "status": o.status,
        "reason": o.reason, "flights": len(o.scores), "lambda_hat": o.lambda_hat,
        "lambda_set_by": cal.set_by(mine.to_dict(orient="records"), o.lambda_hat),
        "rho_star": g.rho_star if g else None, "tested_range": o.tested_range,
        "alpha": options.alpha, "method": options.method,
    }  # fmt: skip
    sel = validation
    if len(sel):
        sel = sel[(sel["controller"] == o.controller) & (sel["condition"] == o.condition)]
    n = len(sel)
    k = int((~sel["assumptions_hold"].astype(bool)).sum()) if n else 0
    lo, hi = cal.clopper_pearson(k, n) if n else (math.nan, math.nan)
    broken = (
        sel[~sel["assumptions_hold"].astype(bool)]["first_failed"].value_counts().to_dict()
        if n
        else {}
    )
    row |= {"validation_flights": n, "validation_broken": k,
            "validation_share": k / n if n else math.nan, "validation_ci": [lo, hi],
            "validation_first_failed": {str(a): int(b) for a, b in broken.items()},
            "validation_agrees": bool(n and lo <= options.alpha)}  # fmt: skip
    return row


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
    import json

    data = json.loads((Path(out) / SUMMARY_FILE).read_text())
    lines = []
    for r in data["certificates"]:
        head = (f"{r['controller']} ({r['condition']}): {r['status']}, {r['flights']} calibration "
                f"flights, alpha {r['alpha']:g}, lambda_hat {_unbounded(r['lambda_hat']):.3g}")  # fmt: skip
        if r.get("lambda_set_by"):
            head += f" (set by the {r['lambda_set_by']})"
        if r["rho_star"] is not None:
            head += f", rho* {r['rho_star']:.3g} (tested to {r['tested_range']:.3g})"
        if r["validation_flights"]:
            lo, hi = r["validation_ci"]
            head += (f"; validation: {r['validation_broken']} of {r['validation_flights']} broke "
                     f"an assumption ({100 * lo:.0f}-{100 * hi:.0f} %)")  # fmt: skip
        if r["reason"]:
            head += f"; {r['reason']}"
        lines.append(head)
    return lines
