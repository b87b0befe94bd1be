"""The fly stage's flights (docs/evaluation.md, Flying the controllers): one job per estimator,
condition, seed and controller (:func:`make_jobs`), each flown on the simulator's RotorPy
vehicle with the VIO emulator (or the camera loop) in the loop
(:func:`qsls.pipeline.sim.closedloop.fly` through :func:`qsls.pipeline.sim.simulate.simulate`),
its bag ingested as a real log's is (:func:`run_job`), on a process pool or a Dask cluster
(:func:`qsls.pipeline.core.workers.run_flights`).

Synthesized controllers act on ``y - r`` and add the reference's feedforward
(:class:`qsls.pipeline.sim.controllers.LinearController`); a runtime-assured flight
(:class:`qsls.pipeline.sim.assured.AssuredController`) flies without a bag, its tick log its
record. Metrics per flight (true state against the reference; emulator error at the VIO
rate): tracking RMS/max of ``||p - p_ref||_2``, perception error RMS/max of ``||e||_inf``,
control effort (RMS of ``u - hover``), smoothness (RMS of ``u[k+1] - u[k]``), a crash flag
with the simulator's reason; against PD on the same estimate (the paper's input figure), the
feedback attitude command's RMS (``reaction_vs_pd``, softness) and its step change's RMS
(``smoothness_vs_pd``, roughness); the body rate and the image blur it makes.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from qsls.pipeline.control.artifacts import load_controller_dir
from qsls.pipeline.control.monitor import OFF, monitor_of
from qsls.pipeline.core.config import merge
from qsls.pipeline.core.errors import InputError, QslsError
from qsls.pipeline.core.units import NS
from qsls.pipeline.evaluate.conditions import flight_conditions
from qsls.pipeline.fly.assured import ASSURED_SUFFIX
from qsls.pipeline.fly.findings import PAPER_CONTROLLERS
from qsls.pipeline.fly.inputs import (
    PdHeightController,
    command_offset,
    error_reaction,
    input_comparison,
    motion_metrics,
    pd_on_same_estimate,
)
from qsls.pipeline.fly.options import FlyOptions
from qsls.pipeline.fly.paper import circle_metrics
from qsls.pipeline.ingest.options import IngestOptions
from qsls.pipeline.ingest.stage import ingest
from qsls.pipeline.sim.assured import assured_controller
from qsls.pipeline.sim.closedloop import fly
from qsls.pipeline.sim.controllers import make_controller
from qsls.pipeline.sim.options import SimOptions
from qsls.pipeline.sim.simulate import simulate
from qsls.pipeline.sim.ticks import TickLog, tick_log
from qsls.pipeline.sim.vehicle import Vehicle


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


def select_controllers(folders: list[Path], names: list[str] | None) -> list[Path]:
    """The controller folders named in ``names`` (``controllers``); default: the paper's four
    where given, else all."""
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


def pd_gain_of(folders: Sequence[Path]) -> tuple[tuple[float, ...], ...] | None:
    """``K`` of a static-gain ``pd`` controller among the folders (synth's PD), if any."""
    for f in folders:
        if f.name == "pd":
            K = load_controller_dir(f).controller.K
            if K is not None:  # on the measured channels (the attitude plant's are padded)
                return tuple(tuple(float(v) for v in row[:6]) for row in K)
    return None


def make_jobs(
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


def monitored(folder: Path) -> bool:
    """Whether the controller in ``folder`` has an onboard monitor (docs/monitor.md: a robust
    certificate, certified or relaxed, with ``rho*``), so it can fly runtime-assured."""
    return any(k != OFF for k in monitor_of(load_controller_dir(folder)).kind)
