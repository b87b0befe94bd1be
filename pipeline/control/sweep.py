"""``qsls sweep``: which settings are feasible, over a grid, locally or on a Dask cluster.

The grid is the Cartesian product of the values given for any of ``S`` (numbers or
error-model names), ``eps_e``, ``radius``, ``delta``, ``T``, ``q_scale`` / ``r_scale``
(multiplying ``Q`` / ``R``), ``eps_w``, ``norm``, ``cost``, ``robust``,
``strictly_proper``; every other setting comes from the base options. Each point is
resolved and solved as ``qsls synth`` does it (:func:`qsls.pipeline.control.problem.resolve`,
:func:`qsls.pipeline.control.synth.design`) and its row is the projection of that design's
certificate body. A robust point that cannot be feasible is answered without the solver and
marked ``skipped``: by the necessary condition ``(S + eps_e/r) N_lower < 1``
(:func:`qsls.pipeline.control.guarantee.necessary_condition`), or (with ``s_max_curve``)
by ``S`` above its setting's largest feasible ``S``, computed first
(:func:`mark_above_s_max`).

Points are grouped by problem structure (``T``, norm, cost, robust, timing) and handed out
in chunks; a worker process keeps its compiled problems (:func:`qsls.pipeline.control.sls.get_problem`),
so a structure is compiled once per worker and then only re-solved with new Parameter
values. The same chunk function runs on a local process pool (``jobs``) or on a
``dask.distributed`` cluster (``scheduler``): the table is the same either way (the solves
are cold, so a point's answer does not depend on what its worker solved before).

Outputs: ``sweep.parquet`` and ``sweep.csv`` (grid values, resolved numbers, ``status``,
``feasible``, ``cost``, norms, ``gamma``, ``margin``, residuals), ``s_max.parquet`` /
``s_max.csv`` (the largest feasible ``S`` for every ``T`` and error setting of the grid),
``feasibility.png`` and ``s_max_vs_T.png``: byte-identical for the same inputs. Each point's
``build_time_s`` / ``solve_time_s`` go to the manifest's ``results.timings`` (the wall time
is the only thing that differs between runs)
"""

from __future__ import annotations

import itertools
import math
import os
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.control import largest_s, sls
from qsls.pipeline.control.costs import QR, cost_of
from qsls.pipeline.control.figures import feasibility_figure, s_max_figure
from qsls.pipeline.control.guarantee import necessary_condition
from qsls.pipeline.control.nominal import pd_responses
from qsls.pipeline.control.options import AXES as AXES
from qsls.pipeline.control.options import DASK_SCHEMES as DASK_SCHEMES
from qsls.pipeline.control.options import ProblemOptions, check_scheduler
from qsls.pipeline.control.options import SweepOptions as SweepOptions
from qsls.pipeline.control.options import SweepSection as SweepSection
from qsls.pipeline.control.pdgain import PDGains
from qsls.pipeline.control.problem import resolve
from qsls.pipeline.control.sls import Shape
from qsls.pipeline.control.status import SOLVER_INACCURATE
from qsls.pipeline.control.synth import (
    IMITATE_NAMED,
    design,
    imitation_target,
    nominal_from_folder,
    warn_size,
)
from qsls.pipeline.core.artifacts import StageWriter, check_output
from qsls.pipeline.core.cluster import run_dask
from qsls.pipeline.core.config import validate
from qsls.pipeline.core.errors import ConfigError, InputError
from qsls.pipeline.core.plant import plant_model
from qsls.pipeline.core.pools import pool_size, run_tasks
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.premise.choose import ModelInput, error_model_file, read_model
from qsls.pipeline.premise.numbers import PremiseNumbers
from qsls.pipeline.premise.record import PREMISE_COLUMNS, premise_columns

SWEEP_FILE = "sweep.parquet"
"""One row per grid point (``sweep.csv`` beside it holds the same)."""
S_MAX_FILE = "s_max.parquet"
"""The largest feasible ``S`` per setting (``s_max_curve``)."""
FEASIBILITY_FIGURE = "feasibility.png"
S_MAX_FIGURE = "s_max_vs_T.png"
TIMING = ("build_time_s", "solve_time_s")
RESULT_COLUMNS = (
    "status", "feasible", "skipped", "cost_value", "norm_phi_xy", "norm_N", "norm_phi_xx",
    "robustness_lhs", "margin", "rho_star", "gamma", "gamma_strict", "achievability_residual",
    "realization_error", "solver_status", *TIMING,
)  # fmt: skip


# --------------------------------------------------------------------------- points
def grid_points(options: SweepOptions, em: Any, training: Any = None) -> list[dict[str, Any]]:
    """One plain dict per grid point: the grid values, the point's resolved problem
    (:class:`~qsls.pipeline.control.problem.Resolved`, as ``qsls synth`` resolves it), the
    premise's violated shares (:func:`premise_fields`) and everything a worker needs
    (picklable)."""
    axes = list(options.grid)
    base = options.model_dump(exclude={"grid", "certify", "s_max_curve", "chunks_per_job"})
    points: list[dict[str, Any]] = []
    mi = ModelInput(em, training=training)
    for i, combo in enumerate(itertools.product(*(options.grid[a] for a in axes))):
        gv = dict(zip(axes, combo, strict=True))
        upd = {k: v for k, v in gv.items() if k not in ("q_scale", "r_scale")}
        try:
            opts = validate(ProblemOptions, {**base, **upd}, "grid point")
        except ConfigError as exc:
            raise ConfigError(f"grid point {gv}: {exc}") from None
        r = resolve(opts, mi)
        qs, rs = float(gv.get("q_scale", 1.0)), float(gv.get("r_scale", 1.0))
        if qs <= 0 or rs <= 0:
            raise ConfigError(f"grid point {gv}: q_scale and r_scale must be > 0")
        r = replace(r, Q=r.Q * qs, R=r.R * rs)
        points.append(
            {
                "index": i,
                "grid": {
                    k: (v if isinstance(v, int | float | str | bool) else str(v))
                    for k, v in gv.items()
                },
                "resolved": r,
                "structure": r.structure(  # the config's name: the cost
                    opts.T, opts.norm, cost_of(opts.cost), opts.robust, opts.strictly_proper
                ),
                "T": opts.T,
                "norm": opts.norm,
                "cost": opts.cost,
                "robust": opts.robust,
                "strictly_proper": opts.strictly_proper,
                "S": r.numbers.S,
                "eps_e": r.numbers.eps,
                "radius": r.numbers.radius,
                "delta": r.numbers.delta,
                "necessary": necessary_condition(
                    r.numbers, r.shape.state_scale, r.shape.error_scale
                ),
                "eps_w": r.numbers.eps_w,
                "eps_o_value": r.numbers.eps_o,
                "m_value": r.numbers.m,
                "gate_value": r.numbers.gate,
                "state_scale": list(r.shape.state_scale),
                "error_scale": list(r.shape.error_scale),
                "measure": r.shape.measure,
                "dt": opts.dt,
                "mass": opts.mass,
                "plant": opts.plant,
                "H": opts.H,
                "kp": list(opts.pd.kp),
                "kd": list(opts.pd.kd),
                "imitate": opts.imitate,
                "solver": opts.solver,
                "certify": options.certify,
                **(premise_columns(r.premise, r.numbers) if r.premise else _no_premise(r)),
            }
        )
    return points


def _no_premise(r: Any) -> dict[str, Any]:
    return {
        "premise_holds": True, "eps_e_violated": math.nan, "S_violated": math.nan,
        "tested_range": math.nan, "m": r.numbers.m, "eps_o": r.numbers.eps_o,
    }  # fmt: skip


def _shape(p: dict[str, Any]) -> Any:
    return Shape(
        tuple(p["state_scale"]), tuple(p["error_scale"]), p["measure"], p["m_value"],
        p["gate_value"] is not None,
    )  # fmt: skip


def structure_key(p: dict[str, Any]) -> tuple:
    return (
        p["measure"],
        tuple(p["state_scale"]),
        tuple(p["error_scale"]),
        p["m_value"],
        p["gate_value"],
        p["T"],
        p["norm"],
        p["cost"],
        p["robust"],
        p["strictly_proper"],
        p["dt"],
        p["mass"],
        p.get("plant", "hover"),
        str(p["H"]),
    )


def point_cost(p: dict[str, Any]) -> float:
    """Rough relative solve time of a point (interior-point work grows like T^1.5 here;
    points answered without the solver cost nothing)."""
    if skip_reason(p):
        return 0.01
    return float(p["T"]) ** 1.5


NECESSARY = "necessary condition (S + eps_e/r) N_lower < 1 fails"
ABOVE_S_MAX = "S above the largest feasible S of this setting (Dinkelbach bound)"
S_MAX_TOL = 1e-6
"""How far (relative) above the Dinkelbach bound a point's S must be to be answered infeasible
without the solver: the bound is exact up to the solver's tolerance (about 1e-8)."""


def skip_reason(p: dict[str, Any]) -> str:
    """Why a robust point cannot be feasible, answered without the solver (empty: solve it):
    the necessary condition, or ``S`` above the setting's largest feasible ``S``
    (:func:`mark_above_s_max`)."""
    if not p["robust"]:
        return ""
    if p["necessary"] >= 1.0:
        return NECESSARY
    return ABOVE_S_MAX if p.get("above_s_max") else ""


def mark_above_s_max(points: list[dict[str, Any]], upper: dict[tuple, float]) -> int:
    """Mark the robust points whose ``S`` exceeds ``max rho - eps_e / r`` of their setting
    (``upper``: the setting's bound on ``max rho``, :meth:`qsls.pipeline.control.largest_s.MaxRatio.upper`)
    by more than :data:`S_MAX_TOL`: the robustness constraint ``(S + eps_e/r) N + ... <= 1 - ...``
    has no solution there, whatever the norm, cost, weights or timing (they do not enter
    it), and a velocity gate only adds constraints. Returns how many were marked."""
    n = 0
    for p in points:
        u = upper.get(setting_key(p))
        if u is None or not p["robust"] or p["necessary"] >= 1.0:
            continue
        if p["S"] > u - p["eps_e"] / p["radius"] + S_MAX_TOL * max(1.0, abs(u)):
            p["above_s_max"] = True
            n += 1
    return n


def make_chunks(points: list[dict[str, Any]], n_chunks: int) -> list[list[dict[str, Any]]]:
    """Chunks of about equal estimated cost, contiguous in structure order (a chunk rarely
    spans two structures, so a worker compiles few problems), largest first (so the pool
    does not finish on one long chunk)."""
    ordered = sorted(points, key=lambda p: (structure_key(p), p["index"]))
    n_chunks = max(1, min(n_chunks, len(ordered)))
    total = sum(point_cost(p) for p in ordered)
    chunks: list[list[dict[str, Any]]] = [[]]
    acc = 0.0
    for p in ordered:
        if chunks[-1] and acc >= total / n_chunks * len(chunks) and len(chunks) < n_chunks:
            chunks.append([])
        chunks[-1].append(p)
        acc += point_cost(p)
    chunks.sort(key=lambda c: -sum(point_cost(p) for p in c))
    return chunks


# --------------------------------------------------------------------------- worker
WORKER_MODULES = (
    "threadpoolctl", "cvxpy", "clarabel", "qsls.pipeline.control.synth",
    "qsls.pipeline.control.largest_s", "qsls.pipeline.control.certify",
    "qsls.pipeline.control.nominal", "qsls.pipeline.control.guarantee",
)  # fmt: skip
"""What the pool's tasks (:func:`run_chunk`, :func:`s_max_task`) import."""


def preload_workers() -> None:
    """Import :data:`WORKER_MODULES` in this process before a local pool forks its workers:
    forked workers inherit them, instead of each importing cvxpy, the solver and the
    synthesis again in every pool phase (about a second of CPU per worker and phase)."""
    import importlib

    for name in WORKER_MODULES:
        importlib.import_module(name)


def _model(p: dict[str, Any]) -> Any:
    H = None if p["H"] is None else np.asarray(p["H"])
    return plant_model(p.get("plant", "hover"), dt=p["dt"], mass=p["mass"], H=H)


def run_point(p: dict[str, Any]) -> dict[str, Any]:
    """Solve (and certify) one grid point: :func:`qsls.pipeline.control.synth.design`, the
    path ``qsls synth`` takes, its row the projection of that design; never raises for a
    solver outcome."""
    row: dict[str, Any] = {"index": p["index"], **p["grid"]}
    row.update({f"{k}_value": p[k] for k in ("S", "eps_e", "radius", "delta", "eps_w")})
    row.update({k: p[k] for k in PREMISE_COLUMNS})
    empty: dict[str, Any] = dict.fromkeys(RESULT_COLUMNS, math.nan)
    empty.update(
        status="", feasible=False, skipped=False, solver_status="", build_time_s=0.0,
        solve_time_s=0.0,
    )  # fmt: skip
    row.update(empty)
    why = skip_reason(p)
    if why:  # answered without the solver
        row.update(status="infeasible", skipped=True, solver_status=why)
        return row
    d = design(
        p["resolved"], p["structure"], nominal=_nominal(p), solver=p["solver"],
        certify=p["certify"],
    )  # fmt: skip
    sol = d.solution
    row.update(
        solver_status=sol.solver_status,
        build_time_s=sol.build_time_s,
        solve_time_s=sol.solve_time_s,
    )
    if d.body is None:
        row["status"] = "infeasible" if sol.status == "infeasible" else "error"
        return row
    row.update(feasible=True, cost_value=d.cost_value, **project(d.body))
    if p["certify"]:
        row["status"] = d.body.status
    else:
        row["status"] = "solved" if sol.status == "optimal" else SOLVER_INACCURATE
        row["realization_error"] = math.nan
    return row


ROW_FIELDS = {
    "norm_phi_xy": "norm_phi_xy", "norm_phi_xx": "norm_phi_xx_h", "norm_N": "norm_N",
    "robustness_lhs": "robustness_lhs", "margin": "margin", "rho_star": "rho_star",
    "gamma": "gamma", "gamma_strict": "gamma_strict",
    "achievability_residual": "achievability_residual", "realization_error": "realization_error",
}  # fmt: skip
"""A sweep column -> the certificate body's field it shows."""


def project(body: Any) -> dict[str, Any]:
    """A sweep row's certificate columns: the certificate body's numbers (NaN where absent)."""
    out = {}
    for col, f in ROW_FIELDS.items():
        v = getattr(body, f)
        out[col] = math.nan if v is None else v
    return out


def _nominal(p: dict[str, Any]) -> Any:
    """An imitation point's target, as ``qsls synth`` chooses it
    (:func:`qsls.pipeline.control.synth.imitation_target`): the PD's responses, the nominal
    controller of the point's own options (``l1_nominal`` / ``h2_nominal``, solved here
    first), or a controller folder's."""
    if not p["structure"].cost.imitates:
        return None

    r, T, target = p["resolved"], p["T"], p["imitate"]
    if target not in IMITATE_NAMED:
        return nominal_from_folder(Path(target), T)
    done: dict[str, Any] = {}
    if target == "pd":
        done["pd"] = pd_responses(r.model, PDGains(kp=p["kp"], kd=p["kd"]), T)[1]
    else:
        norm = target.removesuffix("_nominal")
        st = r.structure(T, norm, QR, False, p["strictly_proper"])
        sol = sls.solve(r.model, st, r.values(), solver=p["solver"])
        if sol.taps is None:
            raise InputError(f"imitate: {target} failed at this point ({sol.solver_status})")
        done[target] = sol.taps
    return imitation_target(target, T, done)


def run_chunk(chunk: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Run a chunk of points in this process (the unit of work for the pool and Dask), BLAS
    on one thread: each worker is one process per core, and BLAS's own threads only spin
    against the other worker (measured: 9.8 CPU s instead of 5.5 for the same sweep, no
    faster)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        return [run_point(p) for p in chunk]


def s_max_task(spec: dict[str, Any]) -> list[dict[str, Any]]:
    """Largest feasible S (and the smallest ||Phi_xy||) for one ``T`` and error setting and
    every ``eps_e`` of the grid: one Dinkelbach run serves them all (``eps_e`` only shifts
    ``S_max``, :func:`qsls.pipeline.control.largest_s.max_ratio`)."""
    model = _model(spec)
    shape = _shape(spec)
    numbers = PremiseNumbers(
        eps=0.0, S=0.0, radius=spec["radius"], eps_w=spec["eps_w"], delta=spec["delta"],
        eps_o=spec["eps_o_value"], gate=spec["gate_value"],
    )  # fmt: skip
    common = {"strictly_proper": spec["strictly_proper"], "solver": spec["solver"], "shape": shape}
    ratio = largest_s.max_ratio(model, spec["T"], numbers, **common)
    min_xy = largest_s.min_phi_xy(
        model, spec["T"], strictly_proper=spec["strictly_proper"], solver=spec["solver"],
        shape=shape,
    )  # fmt: skip
    keep = ("T", "radius", "eps_w", "delta", "strictly_proper")
    upper = ratio.upper(min_xy)
    rows = []
    for eps_e in spec["eps_e"]:
        ms = largest_s.max_feasible_s(
            model, spec["T"], replace(numbers, eps=eps_e), ratio=ratio, **common
        )
        rows.append({**{k: spec[k] for k in keep}, "eps_e": eps_e, "s_max": ms.s_max,
                     "min_norm_phi_xy": min_xy, "key": spec["key"], "ratio_upper": upper})  # fmt: skip
    return rows


S_MAX_KEYS = ("T", "eps_e", "radius", "eps_w", "delta", "strictly_proper")


SETTING_KEYS = ("T", "radius", "eps_w", "delta", "strictly_proper", "dt", "mass", "eps_o_value",
                "m_value", "measure", "gate_value")  # fmt: skip


def setting_key(p: dict[str, Any]) -> tuple:
    """What the robustness constraint's feasibility depends on besides ``S`` and ``eps_e``."""
    return (*(p[x] for x in SETTING_KEYS), str(p["H"]), str(p["state_scale"]),
            str(p["error_scale"]), p.get("plant", "hover"))  # fmt: skip


def s_max_specs(points: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One task per ``T`` and error setting, with the ``eps_e`` values it answers for."""
    keys = SETTING_KEYS
    seen: dict[tuple, dict[str, Any]] = {}
    for p in points:
        k = setting_key(p)
        if k not in seen:
            seen[k] = {
                **{x: p[x] for x in keys}, "H": p["H"], "plant": p.get("plant", "hover"), "solver": p["solver"],
                "state_scale": p["state_scale"], "error_scale": p["error_scale"], "eps_e": [],
                "key": k,
            }  # fmt: skip
        if p["eps_e"] not in seen[k]["eps_e"]:
            seen[k]["eps_e"].append(p["eps_e"])
    return sorted(seen.values(), key=lambda s: tuple(-1.0 if s[x] is None else s[x] for x in keys))


def s_max_table(results: list[list[dict[str, Any]]]) -> Any:
    """The tasks' rows in one table, ordered by ``T`` and setting (``eps_e`` before ``radius``)."""
    import pandas as pd

    rows = sorted(
        (r for res in results for r in res), key=lambda r: tuple(r[k] for k in S_MAX_KEYS)
    )
    return pd.DataFrame(rows, columns=[*S_MAX_KEYS, "s_max", "min_norm_phi_xy"])


# --------------------------------------------------------------------------- sweep
@dataclass(frozen=True)
class SweepResult:
    out: Path
    n_points: int
    counts: dict[str, int]
    n_feasible: int
    executor: str
    table: Any = field(repr=False)
    s_max: Any = field(repr=False)

    def summary(self) -> dict[str, Any]:
        out = {
            "out": self.out.as_posix(),
            "points": self.n_points,
            "feasible": self.n_feasible,
            "executor": self.executor,
        }
        out.update({f"status {k}": v for k, v in sorted(self.counts.items())})
        if self.s_max is not None and len(self.s_max):
            for _, r in self.s_max.iterrows():
                v = float(r["s_max"])
                out[f"largest feasible S at T={int(r['T'])}"] = v if v >= 0 else "none feasible"
        return out


def compute(
    options: SweepOptions,
    *,
    error_model: Path | None = None,
    jobs: int | None = None,
    scheduler: str | None = None,
    worker_timeout: float = 60.0,
    progress: Progress = NULL_PROGRESS,
) -> tuple[Any, Any, str]:
    """The sweep table, the largest-feasible-S table and the executor's description."""
    import pandas as pd

    if scheduler is not None:
        scheduler = check_scheduler(scheduler)
    mi = read_model(error_model)
    points = grid_points(options, mi.model, mi.training)
    if jobs is not None and jobs < 0:
        raise ConfigError(f"--jobs must be 0 (every core) or more, got {jobs}")
    jobs = jobs or (os.cpu_count() or 1)  # the chunking follows what was asked
    workers = jobs if scheduler is None else 8
    n = pool_size(jobs)
    specs = s_max_specs(points) if options.s_max_curve else []
    warn_size(max(int(p["T"]) for p in points), len(points), progress)
    # the count is tasks, not points: name both kinds ("sweep: 3/6" read as 6 points)
    searches = f", {len(specs)} largest-S searches" if specs else ""
    progress.start(f"sweep ({len(points)} points{searches})", total=len(points) + len(specs))

    def execute(tasks: list[tuple[Any, Any]], weights: list[int]) -> list[Any]:
        if not tasks:
            return []
        if scheduler is not None:
            return run_dask(
                tasks, scheduler, lambda i: progress.advance(weights[i]), progress.note,
                worker_timeout, what="sweep",
            )  # fmt: skip
        if n > 1 and len(tasks) > 1:
            preload_workers()
        return run_tasks(tasks, n, lambda i: progress.advance(weights[i]))

    # first the largest feasible S of every setting: it answers the points above it
    s_results = execute([(s_max_task, s) for s in specs], [1] * len(specs))
    mark_above_s_max(points, {r["key"]: r["ratio_upper"] for res in s_results for r in res})
    chunks = make_chunks(points, workers * options.chunks_per_job)
    results = execute([(run_chunk, c) for c in chunks], [len(c) for c in chunks])
    if scheduler is not None:
        executor = f"dask {scheduler}"
    else:
        executor = f"local, {n} process{'es' if n > 1 else ''}"
    progress.finish()
    rows = [r for res in results for r in res]
    table = pd.DataFrame(rows).sort_values("index", kind="stable").reset_index(drop=True)
    for axis in options.grid:  # an axis mixing numbers and names is stored as text
        if len({isinstance(v, str) for v in table[axis]}) > 1:
            table[axis] = table[axis].map(str)
    smax = s_max_table(s_results) if specs else pd.DataFrame()
    return table, smax, executor


def _timings(table: Any) -> dict[str, Any]:
    """Totals and ``{index: [build_time_s, solve_time_s]}`` per point, for the manifest."""
    return {
        "build_time_s": float(table["build_time_s"].sum()),
        "solve_time_s": float(table["solve_time_s"].sum()),
        "points": {
            str(int(i)): [float(b), float(s)]
            for i, b, s in zip(
                table["index"], table["build_time_s"], table["solve_time_s"], strict=True
            )
        },
    }


def sweep(
    options: SweepOptions,
    out: Path,
    *,
    error_model: Path | None = None,
    jobs: int | None = None,
    scheduler: str | None = None,
    worker_timeout: float = 60.0,
    force: bool = False,
    progress: Progress = NULL_PROGRESS,
) -> SweepResult:
    """Run the grid of ``options`` and write the table and figures to ``out``; on a Dask
    cluster (``scheduler``), wait up to ``worker_timeout`` s for a worker."""
    if scheduler is not None:
        scheduler = check_scheduler(scheduler)
    if worker_timeout <= 0:
        raise ConfigError(f"--wait-workers must be > 0 s, got {worker_timeout:g}")
    check_output(out, force, [error_model] if error_model is not None else [])
    table, smax, executor = compute(
        options, error_model=error_model, jobs=jobs, scheduler=scheduler,
        worker_timeout=worker_timeout, progress=progress,
    )  # fmt: skip
    timings = _timings(table)
    table = table.drop(columns=list(TIMING))
    inputs = [error_model_file(error_model)] if error_model is not None else []
    with StageWriter(out, "sweep", options=options, inputs=inputs, force=force) as w:
        w.write_parquet(SWEEP_FILE, table)
        w.write_text("sweep.csv", table.to_csv(index=False))
        if len(smax):
            w.write_parquet(S_MAX_FILE, smax)
            w.write_text("s_max.csv", smax.to_csv(index=False))
        w.write_figure(FEASIBILITY_FIGURE, feasibility_figure(table, options, smax))
        if len(smax):
            w.write_figure(S_MAX_FIGURE, s_max_figure(smax))
        counts = Counter(table["status"])
        w.results.update(
            points=len(table),
            feasible=int(table["feasible"].sum()),
            counts=dict(counts),
            executor=executor,
            timings=timings,
        )
    return SweepResult(
        Path(out), len(table), dict(counts), int(table["feasible"].sum()), executor, table, smax
    )
