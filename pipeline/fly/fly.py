"""``qsls fly``: the paper's four controllers and SE3 flown side by side.

Every controller (PD, nominal L1, L1 robust, L1 robust imitation from a synth folder, plus
RotorPy's SE3 controller of the training flights) is flown on the simulator's RotorPy
vehicle with the VIO emulator in the loop (:func:`qsls.pipeline.sim.closedloop.fly` through
:func:`qsls.pipeline.sim.simulate.simulate`), on the circle, in each perception condition
and for each seed. Synthesized controllers act on ``y - r`` and add the reference's
feedforward (:class:`qsls.pipeline.sim.controllers.LinearController`). ``vio`` picks the
estimator (the emulator or the camera loop); a list flies every controller with each, the
results keyed by estimator (:mod:`qsls.pipeline.fly.estimators`).

With ``assured`` each controller that has an onboard monitor also flies runtime-assured on
the same seeds (:class:`qsls.pipeline.sim.assured.AssuredController`: until its monitor
trips, then the fallback), without a bag and apart from every other table: ``assured.parquet``,
and beside it the comparison with the controller alone and PD alone and the monitor's catch
share (:mod:`qsls.pipeline.fly.assured`; docs/monitor.md, The fallback).

Each flight is written as a bag like a real log and goes through ``ingest`` exactly as a
real flight does; the ingested ``flight.parquet`` is what the bound check
(:mod:`qsls.pipeline.evaluate.bound`) reads. Flights run in parallel on a process pool.

Metrics per flight (true state against the reference; emulator error at the VIO rate):
tracking RMS/max of ``||p - p_ref||_2``, perception error RMS/max of ``||e||_inf``, control
effort (RMS of ``u - hover``), smoothness (RMS of ``u[k+1] - u[k]``), a crash flag with the
simulator's reason; against PD on the same estimate (the paper's input figure), the
feedback attitude command's RMS (``reaction_vs_pd``, softness) and its step change's RMS
(``smoothness_vs_pd``, roughness); the body rate and the image blur it makes. Then per
controller and condition the mean over seeds, the paper's figures, and the paper's four
findings (paper, Results), each paired by seed with a 95% interval and a verdict in
``findings.json`` (:mod:`qsls.pipeline.fly.paired`) and ``comparison.md``:

1. regular perception: every controller tracks, and PD tracks best;
2. degraded perception: the robust ``qr``-cost controller (``l1_robust``) has the lowest
   perception error;
3. every controller's perception error stays below the bound;
4. the robust controllers react more softly than PD would on the same estimate.
"""

from __future__ import annotations

import itertools
import math
import shutil
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from qsls.pipeline.control.artifacts import load_controller_dir
from qsls.pipeline.control.innovation import NO_INNOVATION
from qsls.pipeline.control.monitor import (
    OFF,
    envelope_peak,
    first_test,
    innovation_of,
    monitor_of,
    onboard_flags,
    trip_summary,
)
from qsls.pipeline.core.artifacts import StageWriter, check_output
from qsls.pipeline.core.config import merge
from qsls.pipeline.core.errors import InputError, QslsError
from qsls.pipeline.core.pools import pool_size, run_tasks
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.core.units import NS
from qsls.pipeline.errormodel.model import load_error_model, resolve_model
from qsls.pipeline.evaluate.assumptions import FlownLog, check_assumptions, crashed
from qsls.pipeline.evaluate.bound import (
    ControllerBound,
    EvaluateResult,
    bound_check,
    check_model_hash,
    expand_controllers,
    load_bounds,
    load_training,
    weighted_bounds,
    write_tables,
)
from qsls.pipeline.evaluate.certified import (
    certificate_for,
    certified_premise,
    load_conditioned,
    outside_calibration,
    refuse_evidence_seeds,
)
from qsls.pipeline.evaluate.conditions import flight_conditions
from qsls.pipeline.evaluate.figures import write_fly_figures
from qsls.pipeline.evaluate.options import FlyOptions as FlyOptions
from qsls.pipeline.evaluate.options import IngestOptions, SimOptions
from qsls.pipeline.evaluate.options import Vio as Vio
from qsls.pipeline.evaluate.verdict import ASSUMPTIONS_FILE, controller_promises
from qsls.pipeline.fly.assured import (
    ASSURED_FILE,
    ASSURED_SUFFIX,
    ESTIMATOR,
    assured_comparison,
    catch_share,
    trip_columns,
)
from qsls.pipeline.fly.estimators import findings_markdown, keyed, write_by_estimator
from qsls.pipeline.fly.findings import PAPER_CONTROLLERS, ROBUST_QR, compare_with_paper
from qsls.pipeline.fly.inputs import (
    PdHeightController,
    command_offset,
    error_reaction,
    input_comparison,
    motion_metrics,
    pd_on_same_estimate,
)
from qsls.pipeline.fly.paired import (
    FINDINGS_FILE,
    comparison_markdown,
    finding3,
    paired_findings,
    replace_finding,
)
from qsls.pipeline.fly.paper import circle_metrics
from qsls.pipeline.ingest.flight import read_flight
from qsls.pipeline.ingest.stage import ingest
from qsls.pipeline.sim.assured import assured_controller
from qsls.pipeline.sim.closedloop import fly
from qsls.pipeline.sim.controllers import make_controller
from qsls.pipeline.sim.simulate import simulate
from qsls.pipeline.sim.ticks import TICKS_FILE, TickLog, tick_log
from qsls.pipeline.sim.vehicle import Vehicle


# --------------------------------------------------------------------------- one flight
@dataclass(frozen=True)
class FlyJob:
    name: str
    controller: str
    spec: str  # "se3" or a controller folder
    condition: str
    seed: int
    sim: dict[str, Any]
    ingest: dict[str, Any]
    sim_dir: str
    flight_dir: str
    pd_gain: tuple[tuple[float, ...], ...] | None = None  # K of the flown PD, if any
    pd_z: bool = False  # thrust from PD (paper's setup), for synthesized controllers
    estimator: str = "emulator"  # the vio kind of sim (what the results are keyed by)
    assured: str | None = None  # a runtime-assured flight: its fallback (pd | hold)


@dataclass
class FlyOutcome:
    name: str
    controller: str
    condition: str
    seed: int
    metrics: dict[str, Any]
    ingest_error: str | None
    t_ctrl: np.ndarray  # (k,) s
    x_ctrl: np.ndarray  # (k, 6) truth at the controller ticks
    ref_ctrl: np.ndarray  # (k, 6)
    u_ctrl: np.ndarray  # (k, 3) absolute input, paper signs
    y_ctrl: np.ndarray  # (k, 6) what the controller read (before its gate, if any)
    t_vio: np.ndarray  # (m,) s
    e_norm: np.ndarray  # (m,) ||e||_inf of the emulator
    u_pd: np.ndarray  # (k, 3) what PD would command from the same estimate
    uff_ctrl: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    """(k, 3) the reference's feedforward at the controller ticks (paper signs)."""
    extra: dict[str, Any] = field(default_factory=dict)
    estimator: str = "emulator"


def run_job(job: FlyJob) -> FlyOutcome:
    """Fly one controller (simulate: closed loop + bag), then ingest the bag. A runtime-assured
    flight (``job.assured``) is flown without a bag: its tick log is its record."""
    data = merge(
        job.sim,
        {
            "seed": job.seed,
            "controller": {"kind": job.spec},
            "vio": {"perception": job.condition},
        },
    )
    opts = SimOptions.model_validate(data)
    ctrl: Any = None
    if job.pd_z and job.spec not in ("se3", "pd") and job.controller != "pd":
        ctrl = PdHeightController.build(opts, job.pd_gain)
    ingest_error = None
    if job.assured is not None:
        ctrl = _assured(job, opts, ctrl)
        f = fly(opts, ctrl)
        ticks = tick_log(f)
    else:
        res = simulate(opts, Path(job.sim_dir), force=True, controller=ctrl)
        f, ticks = res.flight, res.ticks
        try:
            ingest(
                [res.bag], IngestOptions.model_validate(job.ingest), Path(job.flight_dir),
                force=True,
            )  # fmt: skip
        except QslsError as exc:
            ingest_error = str(exc)
    t_ctrl = f.ctrl_t_ns / NS
    u_pd = pd_on_same_estimate(opts, f.mass, t_ctrl, f.ctrl_y, f.ctrl_ref, job.pd_gain)
    u_off = command_offset(opts, f.mass, t_ctrl)
    start = float(opts.reference.start_s)
    on = t_ctrl >= start
    circle = circle_metrics(
        f.t_ns / NS, np.linalg.norm(f.x[:, :3] - f.ref[:, :3], axis=1), f.vio_t_ns / NS,
        np.abs(f.vio_e).max(axis=1) if len(f.vio_e) else np.zeros(0), start,
    )  # fmt: skip
    react = input_comparison(f.ctrl_u[on], u_pd[on], u_off[on])
    circle["reaction_vs_pd_circle"] = react["reaction_vs_pd"]
    return FlyOutcome(
        name=job.name,
        controller=job.controller,
        condition=job.condition,
        seed=job.seed,
        metrics={
            **f.metrics(),
            **input_comparison(f.ctrl_u, u_pd, u_off),
            **motion_metrics(opts, job.seed, f.vio_x, f.vio_w, f.emulator),
            **error_reaction(opts, f.mass, f.ctrl_y - ticks.x, job.pd_gain),
            **circle,
        },
        ingest_error=ingest_error,
        t_ctrl=t_ctrl,
        x_ctrl=ticks.x,
        ref_ctrl=f.ctrl_ref,
        u_ctrl=f.ctrl_u,
        y_ctrl=f.ctrl_y,
        t_vio=f.vio_t_ns / NS,
        e_norm=np.abs(f.vio_e).max(axis=1),
        u_pd=u_pd,
        uff_ctrl=ticks.uff,
        extra={"crash_time_s": f.crash_time_s, "lipschitz": f.lipschitz, "mass": f.mass,
               "conditions": flight_conditions(opts.model_dump(mode="json")),
               **({"flew": list(ctrl.flew), "bits": list(ctrl.bits)} if job.assured else {})},
        estimator=job.estimator,
    )  # fmt: skip


def _assured(job: FlyJob, opts: SimOptions, primary: Any) -> Any:
    """The runtime-assured form of ``job``'s controller (flown as ``primary`` if given, e.g.
    with PD's height channel): :func:`qsls.pipeline.sim.assured.assured_controller`."""
    # the mass the controller assumes, as the controller alone flies it (closedloop.fly)
    mass = opts.px4.controller_mass or Vehicle(opts.vehicle).mass
    if primary is None:
        primary = make_controller(opts.controller, mass)
    return assured_controller(
        Path(job.spec),
        primary,
        mass,
        opts.controller.pd,
        job.pd_gain,
        job.assured,  # type: ignore[arg-type]
    )


def tick_frame(o: FlyOutcome) -> pd.DataFrame:
    """``ticks.parquet`` of a flown flight (:class:`qsls.pipeline.sim.ticks.TickLog`);
    a runtime-assured flight's adds, per tick, the monitor's bits (``monitor_bits``, 0 while
    consistent) and which controller flew (``flew``: the controller's name, then ``pd`` or
    ``hold`` from the trip tick on)."""
    frame = TickLog(o.t_ctrl, o.x_ctrl, o.y_ctrl, o.u_ctrl, o.ref_ctrl, o.uff_ctrl,
                    controller=o.controller).frame()  # fmt: skip
    if "flew" in o.extra:
        frame["monitor_bits"] = np.asarray(o.extra["bits"], dtype=np.int64)
        frame["flew"] = list(o.extra["flew"])
    return frame


def run_jobs(
    jobs: Sequence[FlyJob],
    workers: int,
    progress: Progress,
    scheduler: str | None = None,
    wait_workers: float = 60.0,
) -> list[FlyOutcome]:
    """All flights, on a process pool of ``workers`` or the Dask cluster at ``scheduler`` (in
    order of ``jobs``)."""
    progress.start("flying", total=len(jobs))
    results = run_tasks(
        [(run_job, j) for j in jobs], workers, lambda i: progress.advance(),
        scheduler=scheduler, note=progress.note, worker_timeout=wait_workers, what="fly",
    )  # fmt: skip
    progress.finish()
    return results


# --------------------------------------------------------------------------- result
@dataclass(frozen=True)
class FlyResult(EvaluateResult):
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


# --------------------------------------------------------------------------- analysis
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


def _analyse(
    outcomes: Sequence[FlyOutcome],
    jobs: Sequence[FlyJob],
    bounds: Sequence[ControllerBound],
    training: Any,
    options: FlyOptions,
    by_condition: Mapping[tuple[str, str], ControllerBound] | None = None,
) -> Analysis:
    """Tables, bound checks, assumptions, the paper comparison and the paired findings of one
    estimator's flights (a flight checked against its condition's certificate where
    ``by_condition`` holds one: :func:`certificate_for`)."""
    flights = flight_table(outcomes)
    checks, samples, ref_j = _check_flights(outcomes, jobs, flights, bounds, training, by_condition)
    assumptions = assumption_table(outcomes, bounds, training, by_condition)
    per = _bound_columns(per_controller_table(flights), checks)
    ref_bound = bounds[ref_j] if ref_j is not None else None
    comparison = compare_with_paper(
        per, checks, options.track_threshold_m, ref_bound, options.tie_rel,
        _true_lipschitz(outcomes),
    )  # fmt: skip
    findings = paired_findings(
        flights, checks, ref_bound.name if ref_bound else None, PAPER_CONTROLLERS,
        options.track_threshold_m, _motion_parts(options.sim), assumptions,
        estimator=jobs[0].estimator if jobs else "emulator", strict=premise_rows(bounds),
        norms=gain_norms(bounds),
    )  # fmt: skip
    return Analysis(flights, checks, samples, assumptions, per, comparison, findings)


FLOWN_FILE = "flights.parquet"
"""One row per flight flown (the primary estimator's)."""
PER_CONTROLLER_TABLE = "per_controller.parquet"
"""Per controller and condition, means over seeds (the primary estimator's)."""

CIRCLE_COLUMNS = (
    "tracking_rms_m_circle",
    "tracking_max_m_circle",
    "perception_error_rms_circle",
    "perception_error_max_circle",
    "reaction_vs_pd_circle",
)
"""The metrics over the circle with the paper's 1 s smoothing
(:func:`qsls.pipeline.fly.paper.circle_metrics`)."""


def premise_rows(bounds: Sequence[ControllerBound]) -> list[dict[str, Any]]:
    """Each controller's premise for the paper's strict bound (``R0``, ``S``, ``||Phi_xe||``,
    ``||Phi_ue||``; :func:`qsls.pipeline.fly.paired.strict_bounds`)."""
    return [
        {"name": b.name, "status": b.status, "R0": b.r0, "S": b.numbers.S,
         "norm_phi_xe": b.norm_phi_xy, "norm_phi_ue": b.certificate.get("norm_phi_uy")}
        for b in bounds
        if math.isfinite(b.numbers.S) and math.isfinite(b.norm_phi_xy) and math.isfinite(b.r0)
    ]  # fmt: skip


def gain_norms(bounds: Sequence[ControllerBound]) -> dict[str, dict[str, float]]:
    """``{controller: {phi_xe, phi_ue}}``: the gains from perception error to state and to
    input of each controller's taps."""
    out = {}
    for b in bounds:
        ue = b.certificate.get("norm_phi_uy")
        out[b.name] = {
            "phi_xe": float(b.norm_phi_xy),
            "phi_ue": float(ue) if ue is not None else math.nan,
        }
    return out


def flight_table(outcomes: Sequence[FlyOutcome]) -> pd.DataFrame:
    rows = []
    for o in outcomes:
        m = o.metrics
        rows.append(
            {
                "flight": o.name,
                "controller": o.controller,
                "condition": o.condition,
                "seed": o.seed,
                "duration_s": m["duration_s"],
                "tracking_rms_m": m["tracking_rms_m"],
                "tracking_max_m": m["tracking_max_m"],
                "perception_error_rms": m["perception_error_rms"],
                "perception_error_max": m["perception_error_max"],
                "control_effort_rms": m["control_effort_rms"],
                "control_smoothness_rms": m["control_smoothness_rms"],
                "attitude_smoothness": m["attitude_smoothness"],
                "smoothness_vs_pd": m["smoothness_vs_pd"],
                "reaction_vs_pd": m["reaction_vs_pd"],
                "error_reaction_vs_pd": m["error_reaction_vs_pd"],
                "attitude_diff_from_pd_rms": m["attitude_diff_from_pd_rms"],
                "angular_rate_rms": m["angular_rate_rms"],
                "blur_px_mean": m["blur_px_mean"],
                "features_per_frame": m.get("features_per_frame", math.nan),
                **{k: m.get(k, math.nan) for k in CIRCLE_COLUMNS},
                "crashed": bool(m["crashed"]),
                "crash_reason": m["crash_reason"] or "",
                "ingest_error": o.ingest_error or "",
            }
        )
    return pd.DataFrame(rows)


def per_controller_table(flights: pd.DataFrame) -> pd.DataFrame:
    """Mean over seeds per controller and condition (max for the maxima, sum of crashes)."""
    agg = {
        "tracking_rms_m": "mean",
        "tracking_max_m": "max",
        "perception_error_rms": "mean",
        "perception_error_max": "max",
        "control_effort_rms": "mean",
        "control_smoothness_rms": "mean",
        "smoothness_vs_pd": "mean",
        "reaction_vs_pd": "mean",
        "error_reaction_vs_pd": "mean",
        "attitude_diff_from_pd_rms": "mean",
        "angular_rate_rms": "mean",
        "blur_px_mean": "mean",
        "features_per_frame": "mean",
        **{k: ("max" if "_max_" in k else "mean") for k in CIRCLE_COLUMNS},
        "crashed": "sum",
        "seed": "count",
    }
    agg = {k: v for k, v in agg.items() if k in flights}
    g = flights.groupby(["condition", "controller"], sort=False).agg(agg).reset_index()
    return g.rename(columns={"seed": "flights"})


def _bound_columns(per: pd.DataFrame, checks: pd.DataFrame) -> pd.DataFrame:
    """Add each controller's own bound check (if it has a certificate) to ``per``."""
    if checks.empty:
        return per
    own = checks[checks["controller"] == checks["flown_by"]]
    g = (
        own.groupby(["condition", "controller"], sort=False)
        .agg(
            gamma_strict=("gamma_strict", "first"),
            gamma_max=("gamma", "max"),
            frac_under_gamma=("frac_under_gamma", "mean"),
            frac_under_gamma_strict=("frac_under_gamma_strict", "mean"),
            max_ratio=("max_ratio", "max"),
            gamma_nominal_max=("gamma_nominal", "max"),
            max_nominal_ratio=("nominal_ratio", "max"),
            bound_holds_all=("bound_holds", lambda b: bool(b.astype(bool).all())),
        )
        .reset_index()
    )
    return per.merge(g, on=["condition", "controller"], how="left")


def _select(folders: list[Path], names: list[str] | None) -> list[Path]:
    by_name = {f.name: f for f in folders}
    if names is None:
        chosen = [by_name[n] for n in PAPER_CONTROLLERS if n in by_name]
        return chosen or folders
    missing = [n for n in names if n not in by_name]
    if missing:
        raise InputError(
            f"controllers {', '.join(missing)} not among the given folders "
            f"(have: {', '.join(sorted(by_name))})"
        )
    return [by_name[n] for n in names]


def _pd_gain_of(folders: Sequence[Path]) -> tuple[tuple[float, ...], ...] | None:
    """``K`` of a static-gain ``pd`` controller among the folders (synth's PD), if any."""
    for f in folders:
        if f.name == "pd":
            K = load_controller_dir(f).controller.K
            if K is not None:  # on the measured channels (the attitude plant's are padded)
                return tuple(tuple(float(v) for v in row[:6]) for row in K)
    return None


def _make_jobs(
    specs: Sequence[tuple[str, str]],
    options: FlyOptions,
    *,
    sims: Path,
    flights: Path,
    pd_gain: tuple[tuple[float, ...], ...] | None,
    assured: Sequence[str] = (),
    spec_in: Mapping[tuple[str, str], str] | None = None,
) -> list[FlyJob]:
    """One job per estimator, condition, seed and controller (``specs``:
    ``(name, se3 | folder)``; ``spec_in[(condition, name)]`` replaces the folder in that
    condition: the same taps, certified for it, so an onboard monitor watches that
    condition's premise); with several estimators a flight's name starts with its own.
    Then, per estimator, one runtime-assured job per condition, seed and controller named in
    ``assured`` (its name and controller end in ``_assured``)."""
    spec_in = spec_in or {}
    several = len(options.estimators) > 1
    ingest_opts = options.ingest.model_dump(mode="json")
    jobs = []
    for vio in options.estimators:
        sim = options.sim.model_dump(mode="json")
        sim["duration"] = options.duration
        if vio != "emulator" or several:
            sim["vio"] = {**sim["vio"], "kind": vio}
        if vio == "camera":  # an emulator's dump leaves out the camera's parameters
            sim["vio"]["camera"] = options.sim.vio.camera.model_dump(mode="json")
        grid = itertools.product(options.conditions, options.seeds, specs)
        for cond, seed, (cname, spec) in grid:
            name = f"{vio}_{cond}_s{seed}_{cname}" if several else f"{cond}_s{seed}_{cname}"
            jobs.append(FlyJob(
                name=name, controller=cname, spec=spec_in.get((cond, cname), spec), condition=cond, seed=int(seed), sim=sim,
                ingest=ingest_opts, sim_dir=str(sims / name), flight_dir=str(flights / name),
                pd_gain=pd_gain, pd_z=options.pd_z_for(cname), estimator=vio,
            ))  # fmt: skip
        grid = itertools.product(options.conditions, options.seeds, specs)
        for cond, seed, (cname, spec) in grid:
            if cname not in assured:
                continue
            name = f"{vio}_{cond}_s{seed}_{cname}" if several else f"{cond}_s{seed}_{cname}"
            name += ASSURED_SUFFIX
            jobs.append(FlyJob(
                name=name, controller=cname + ASSURED_SUFFIX,
                spec=spec_in.get((cond, cname), spec), condition=cond,
                seed=int(seed), sim=sim, ingest=ingest_opts, sim_dir=str(sims / name),
                flight_dir=str(flights / name), pd_gain=pd_gain, pd_z=options.pd_z_for(cname),
                estimator=vio, assured=options.fallback,
            ))  # fmt: skip
    return jobs


def _check_flights(
    outcomes: Sequence[FlyOutcome],
    jobs: Sequence[FlyJob],
    flights: pd.DataFrame,
    bounds: Sequence[ControllerBound],
    training: Any,
    by_condition: Mapping[tuple[str, str], ControllerBound] | None = None,
) -> tuple[pd.DataFrame, pd.DataFrame, int | None]:
    """Bound check of every ingested flight against its own controller's certificate (its
    condition's: :func:`certificate_for`) and the robust reference bound (``l1_robust``,
    else the first with a guarantee, index into ``bounds`` returned; its condition's too)."""
    held = [
        (o.name, read_flight(Path(j.flight_dir)))
        for o, j in zip(outcomes, jobs, strict=True)
        if not o.ingest_error
    ]
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


def monitor_columns(
    spec: Any, log: Any, gate: float | None, innovation: Any = NO_INNOVATION,
    u_hover: Any = None,
) -> dict[str, Any]:  # fmt: skip
    """What the onboard premise monitor (docs/monitor.md) would have said on a flown log, the
    envelope and the innovation monitor both
    (:func:`qsls.pipeline.control.monitor.onboard_flags` on ``y - r`` and the deviation command
    ``u - u_hover - uff`` flown, at the controller's ticks, from the reset at take-off): the
    ticks it trips on, the first one's time, the test that tripped first (``envelope``,
    ``outlier count``, ``innovation outlier count``, ``disturbance on vz``) and every test's
    trips in words (:func:`qsls.pipeline.control.monitor.trip_summary`)."""
    du = np.asarray(log.u, float) - np.asarray(log.uff, float)
    du = du - (np.zeros(3) if u_hover is None else np.asarray(u_hover, float))
    t = np.asarray(log.t, float)
    flags = onboard_flags(spec, innovation, np.asarray(log.y) - np.asarray(log.ref), du, gate)
    hit = np.flatnonzero(flags)
    first = int(hit[0]) if len(hit) else None
    dt = float(t[1] - t[0]) if len(t) > 1 else 0.0
    return {
        "monitor_trips": len(hit),
        "monitor_t": float(t[first]) if first is not None else float("nan"),
        "monitor_first": "" if first is None else first_test(int(flags[first])),
        "monitor_summary": "; ".join(trip_summary(flags, dt, t)),
    }


def assumption_table(
    outcomes: Sequence[FlyOutcome],
    bounds: Sequence[ControllerBound],
    training: Any,
    by_condition: Mapping[tuple[str, str], ControllerBound] | None = None,
) -> pd.DataFrame:
    """:func:`qsls.pipeline.evaluate.assumptions.check_assumptions` on every flight a certified
    (or relaxed) robust controller flew, from its own log at its own ticks, against the
    certificate of its condition (:func:`certificate_for`)."""
    named = {b.name: b for b in bounds}
    loaded: dict[Path, tuple[Any, Any, Any, Any]] = {}

    def premise_of(b: ControllerBound) -> tuple[Any, Any, Any, Any]:
        """(premise, monitor, innovation monitor, calibration) of one certificate, read once."""
        if b.folder not in loaded:
            c = certified_premise(b.folder)
            d = load_controller_dir(b.folder) if c is not None else None
            loaded[b.folder] = (
                c,
                monitor_of(d) if d is not None else None,
                innovation_of(d) if d is not None else NO_INNOVATION,
                d.certificate.calibration if d is not None else None,
            )
        return loaded[b.folder]

    rows = []
    for o in outcomes:
        b = certificate_for(o.controller, o.condition, named, by_condition)
        if b is None:
            continue
        c, monitor, innovation, cal = premise_of(b)
        if c is None or len(o.t_ctrl) < 2:
            continue  # a crashed flight is checked on the ticks it flew: a crash is no excuse
        log = FlownLog(o.t_ctrl, o.x_ctrl, o.y_ctrl, o.u_ctrl, o.ref_ctrl, o.uff_ctrl)
        row = check_assumptions(log, c, training.distance)
        row.update(monitor_columns(monitor, log, c.numbers.gate, innovation, c.u_hover))
        if o.metrics.get("crashed"):
            row = crashed(row, o.extra.get("crash_time_s"), o.metrics.get("crash_reason"))
        row["outside_calibration"] = outside_calibration(
            cal, o.condition, float(o.metrics.get("duration_s", o.t_ctrl[-1])), o.estimator,
            o.extra.get("conditions"),
        )  # fmt: skip
        rows.append({"flight": o.name, "controller": o.controller, "status": b.status,
                     "crashed": bool(o.metrics.get("crashed")),
                     "condition": o.condition, "seed": o.seed, **row})  # fmt: skip
    return pd.DataFrame(rows)


def monitored(folder: Path) -> bool:
    """Whether the controller in ``folder`` has an onboard monitor (docs/monitor.md: a robust
    certificate, certified or relaxed, with ``rho*``), so it can fly runtime-assured."""
    return any(k != OFF for k in monitor_of(load_controller_dir(folder)).kind)


def assured_table(
    outcomes: Sequence[FlyOutcome], status: dict[str, str], fallback: str,
    folders: dict[str, Path], *, by_estimator: bool = False,
    by_condition: Mapping[tuple[str, str], ControllerBound] | None = None,
) -> pd.DataFrame:  # fmt: skip
    """One row per runtime-assured flight: its flight-table columns (``controller`` the
    monitored controller's name), the certificate's status and the perception its calibration
    flew in (``calibrated_perception``, empty if not calibrated), the fallback, the handover
    (:func:`qsls.pipeline.fly.assured.trip_columns`) and ``envelope_peak``, the largest
    ``|y_i - r_i| / threshold_i`` over the flight's ticks and envelope channels
    (:func:`qsls.pipeline.control.monitor.envelope_peak`: how close it came to a trip).
    ``by_estimator`` (a stage with several estimators) puts the flight's estimator first.
    A flight's certificate is its condition's where ``by_condition`` holds one (the one its
    monitor watched: :func:`_make_jobs`)."""
    if not outcomes:
        return pd.DataFrame()
    table = flight_table(outcomes)
    base = [o.controller.removesuffix(ASSURED_SUFFIX) for o in outcomes]
    by_condition = by_condition or {}

    def folder(b: str, cond: str) -> Path:
        own = by_condition.get((cond, b))
        return own.folder if own is not None else folders[b]

    where = [folder(b, o.condition) for o, b in zip(outcomes, base, strict=True)]
    cdirs = {f: load_controller_dir(f) for f in dict.fromkeys(where)}
    spec = {f: monitor_of(c) for f, c in cdirs.items()}
    trips = pd.DataFrame([
        {**trip_columns(o.extra["flew"], o.extra["bits"], o.t_ctrl),
         "envelope_peak": envelope_peak(spec[f], o.y_ctrl - o.ref_ctrl, cdirs[f].certificate.gate)}
        for o, f in zip(outcomes, where, strict=True)
    ])  # fmt: skip
    table["controller"] = base
    table.insert(2, "status", [
        own.status if (own := by_condition.get((o.condition, b))) is not None else status.get(b, "")
        for o, b in zip(outcomes, base, strict=True)
    ])  # fmt: skip
    # a calibrated certificate speaks for flights of its calibration's perception only
    perception = {
        f: str(cal.conditions.get("perception", "")) if (cal := c.certificate.calibration) else ""
        for f, c in cdirs.items()
    }
    table.insert(3, "calibrated_perception", [perception[f] for f in where])
    table.insert(4, "fallback", fallback)
    if by_estimator:
        table.insert(0, ESTIMATOR, [o.estimator for o in outcomes])
    return pd.concat([table, trips], axis=1)


def _motion_parts(sim: SimOptions) -> list[str]:
    """The VIO emulator's motion-dependent parts switched on for the flights."""
    return [k for k in ("blur", "motion_drift", "feature_loss") if getattr(sim.vio, k, False)]


def _true_lipschitz(outcomes: Sequence[FlyOutcome]) -> dict[str, float]:
    """The emulator's Lipschitz constant per condition (the largest over flights); none for
    the camera loop's flights (no designed bias field, so no true constant to compare)."""
    true_l: dict[str, float] = {}
    for o in outcomes:
        if o.extra["lipschitz"] is None:
            continue
        true_l[o.condition] = max(true_l.get(o.condition, 0.0), float(o.extra["lipschitz"]))
    return true_l


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
    import time

    t0 = time.perf_counter()
    check_output(Path(out), force)
    model_file, fit_dir = resolve_model(error_model)
    model = load_error_model(model_file)
    folders = _select(expand_controllers(controllers), options.controllers)
    bounds = weighted_bounds(load_bounds(folders), model.state_scale)
    conditioned = load_conditioned(by_condition, [b.name for b in bounds], options.conditions)
    weighted = weighted_bounds(conditioned.values(), model.state_scale)
    conditioned = dict(zip(conditioned, weighted, strict=True))
    promises = controller_promises(
        (b.name, b.certificate) for b in [*bounds, *conditioned.values()]
    )
    refuse_evidence_seeds([*folders, *(b.folder for b in conditioned.values())], options.seeds)
    warnings = [m for b in bounds if (m := check_model_hash(b, model_file, force=force))]
    warnings += [
        m for b in conditioned.values() if (m := check_model_hash(b, model_file, force=force))
    ]
    training = load_training(fit_dir, model, options.state_scale)

    specs: list[tuple[str, str]] = [(b.name, str(b.folder.resolve())) for b in bounds]
    assured = [b.name for b in bounds if monitored(b.folder)] if options.assured else []
    if options.se3:
        specs.append(("se3", "se3"))
    workers = pool_size(options.jobs)

    inputs = list(dict.fromkeys([model_file, *folders, *(b.folder for b in conditioned.values())]))
    with StageWriter(out, "evaluate", options=options, inputs=inputs, force=force) as w:
        # scratch inside the stage's temporary folder: removed before it is published, and
        # reclaimed with it by the next writer if this process is killed (SIGKILL included)
        tmp_root = w.tmp / ".scratch"
        tmp_root.mkdir()
        try:
            jobs = _make_jobs(
                specs, options, sims=w.path("sims") if options.keep_bags else tmp_root,
                flights=w.path("flights"), pd_gain=_pd_gain_of(folders), assured=assured,
                spec_in={k: str(b.folder.resolve()) for k, b in conditioned.items()},
            )  # fmt: skip
            flown = run_jobs(
                jobs, min(workers, len(jobs)), progress, options.scheduler, options.wait_workers
            )
            for o in flown:  # the controller's own log, for an auditor to recompute from
                w.write_parquet(f"flights/{o.name}/{TICKS_FILE}", tick_frame(o))
            # the assured flights are kept apart: every other table is what a run without
            # them writes
            outcomes = [o for o, j in zip(flown, jobs, strict=True) if j.assured is None]
            jobs_flown, jobs = jobs, [j for j in jobs if j.assured is None]
            for o in flown:
                if o.metrics["crashed"]:
                    warnings.append(
                        f"{o.name}: crashed, flight ended safely ({o.metrics['crash_reason']})"
                    )
                if o.ingest_error:
                    warnings.append(
                        f"{o.name}: not bound-checked, ingest failed ({o.ingest_error})"
                    )

            analyses: dict[str, Analysis] = {
                vio: _analyse(
                    [o for o in outcomes if o.estimator == vio],
                    [j for j in jobs if j.estimator == vio], bounds, training, options,
                    conditioned,
                )
                for vio in options.estimators
            }  # fmt: skip
            a = analyses[options.estimators[0]]  # the primary: the stage's own tables
            flights, checks, samples, assumptions = a.flights, a.checks, a.samples, a.assumptions
            per, comparison, findings = a.per, a.comparison, a.findings
            several = len(analyses) > 1
            if several:  # every estimator's flights count in the verdicts (and the table)
                assumptions = pd.concat(
                    [an.assumptions.assign(estimator=vio) for vio, an in analyses.items()
                     if len(an.assumptions)],
                    ignore_index=True,
                ) if any(len(an.assumptions) for an in analyses.values()) else assumptions  # fmt: skip
            if several:
                findings = write_by_estimator(w, analyses)
                # finding 3 counts every estimator's flights (the assumptions of all of them)
                every = pd.concat([an.flights for an in analyses.values()], ignore_index=True)
                findings = replace_finding(
                    findings,
                    finding3(
                        checks, every, None, assumptions if len(assumptions) else None,
                        premise_rows(bounds),
                    ),
                )  # fmt: skip

            w.write_parquet(FLOWN_FILE, flights)
            w.write_parquet(ASSUMPTIONS_FILE, assumptions)
            w.write_parquet(PER_CONTROLLER_TABLE, per)
            w.write_json(FINDINGS_FILE, findings)
            md = comparison_markdown(comparison, per, findings)
            w.write_text(
                "comparison.md", md + ("\n" + findings_markdown(analyses) if several else "")
            )
            if options.figures:
                primary = [o for o in outcomes if o.estimator == options.estimators[0]]
                write_fly_figures(w, primary, options, checks)
            assured_json: dict[str, Any] = {}
            table = pd.DataFrame()
            if options.assured:
                table = assured_table(
                    [o for o, j in zip(flown, jobs_flown, strict=True) if j.assured is not None],
                    {b.name: b.status for b in bounds}, options.fallback,
                    {b.name: b.folder for b in bounds}, by_estimator=several,
                    by_condition=conditioned,
                )  # fmt: skip
                w.write_parquet(ASSURED_FILE, table)
                # with several estimators each assured flight meets its own estimator's flights
                comp = assured_comparison(
                    keyed({v: an.flights for v, an in analyses.items()}) if several else flights,
                    table,
                )
                tripped = int(table["tripped"].sum()) if len(table) else 0
                w.results["assured"] = f"{tripped} of {len(table)} flights handed over"
                assured_json = {
                    "assured": comp.to_dict(orient="records"),
                    "monitor_catch": catch_share(assumptions).to_dict(orient="records"),
                }
            extra_json = {
                "mode": "fly",
                "flights_table": flights.to_dict(orient="records"),
                "per_controller": per.to_dict(orient="records"),
                "comparison": comparison,
                "assumptions": assumptions.to_dict(orient="records"),
                "promises": promises,
                **assured_json,
            }
            totals = write_tables(
                w, checks, samples, warnings, model, options, extra_json, own_only=True
            )
            w.results.update(
                {
                    "mode": "fly",
                    "flights": len(flights),
                    "crashed": int(flights["crashed"].sum()),
                    **{f"finding_{c['finding'][0]}_agrees": c["agrees"] for c in comparison},
                    **{f"finding_{f['id']}_verdict": f["verdict"] for f in findings["findings"]},
                    "controllers": totals,
                    "warnings": len(warnings),
                }
            )
            if several:
                w.results["estimators"] = list(options.estimators)
        finally:
            shutil.rmtree(tmp_root, ignore_errors=True)
    return FlyResult(
        out=Path(out),
        table=checks,
        assumptions=assumptions,
        warnings=tuple(warnings),
        flights=flights,
        per_controller=per,
        comparison=comparison,
        findings=findings,
        wall_time_s=time.perf_counter() - t0,
        assured=table,
        promises=promises,
    )


__all__ = ["PAPER_CONTROLLERS", "FlyOptions", "FlyResult", "fly_evaluate"]
