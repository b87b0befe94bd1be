"""``qsls synth``: from an error model to the paper's controllers, each with a certificate.

One configuration yields the paper's four controllers (paper, Controllers):

- ``pd``: the PD controller, not synthesized; its closed-loop responses truncated to ``T``
  taps are stored (the imitation target and a reference for evaluation);
- ``l1_nominal``: ``c_QR`` in the L1 norm, no robustness constraint;
- ``l1_robust``: ``c_QR`` in the L1 norm with the robustness constraint;
- ``l1_robust_imitation``: ``c_im`` (distance to the nominal's responses, the PD by
  default) in the L1 norm with the robustness constraint;

and with ``norm: h2`` (or ``both``) the H2 variants ``h2_nominal``, ``h2_robust``,
``h2_robust_imitation``. ``controllers: single`` synthesizes one controller from
``norm``, ``cost`` and ``robust`` instead.

Infeasible is an answer: before solving, the necessary condition
``(S + eps_e / r) N_lower < 1`` (``N >= N_lower``, 1 with unit weights, for this plant:
:func:`qsls.pipeline.control.guarantee.min_norm_bound`) is checked, and an infeasible robust problem raises
:class:`InfeasibleError` (exit 3) with a diagnosis: that condition, the smallest achievable
``||Phi_xy||`` at this ``T`` and the largest feasible ``S`` (:func:`max_feasible_s`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, cast

from qsls.pipeline.control import sls
from qsls.pipeline.control.artifacts import (
    CERTIFICATE_FILE,
    CONTROLLER_FILE,
    Certificate,
    CertificateBody,
    Controller,
)
from qsls.pipeline.control.certify import PREMISE_VIOLATED, certify, guarantee_fields
from qsls.pipeline.control.certify import certify as check  # design() has a `certify` flag
from qsls.pipeline.control.costs import cost_of
from qsls.pipeline.control.feasibility import MaxFeasibleSResult as MaxFeasibleSResult
from qsls.pipeline.control.feasibility import diagnose, diagnosis_message
from qsls.pipeline.control.feasibility import max_feasible_s as max_feasible_s
from qsls.pipeline.control.guarantee import Norms, necessary_condition
from qsls.pipeline.control.nominal import pd_responses, spectral_radius, static_gain_norms
from qsls.pipeline.control.options import ProblemOptions as ProblemOptions
from qsls.pipeline.control.options import SynthOptions
from qsls.pipeline.control.pdgain import PDGains
from qsls.pipeline.control.premise import refuse_empty
from qsls.pipeline.control.resolution import ModelInput as ModelInput
from qsls.pipeline.control.resolution import Resolved as Resolved
from qsls.pipeline.control.resolution import read_model as read_model
from qsls.pipeline.control.resolution import resolve as resolve
from qsls.pipeline.control.status import RELAXED, Status
from qsls.pipeline.core.artifacts import StageWriter, check_output
from qsls.pipeline.core.errors import InfeasibleError, InputError, SolverError
from qsls.pipeline.core.plant import NU, NX
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.errormodel.disturbance import RESIDUAL
from qsls.pipeline.errormodel.model import ErrorModel
from qsls.pipeline.errormodel.premise import TrainingStates


# --------------------------------------------------------------------------- one controller
@dataclass(frozen=True)
class Design:
    """One solved controller problem (:func:`design`): the solver's answer and, when it gave
    taps, the certificate's body and the cost. ``qsls synth`` writes it as a controller folder
    (:func:`certified_controller`); a sweep row is its projection."""

    structure: sls.Structure
    solution: sls.Solution
    body: CertificateBody | None = None
    cost_value: float = math.nan


def design(
    r: Resolved,
    structure: sls.Structure,
    *,
    nominal: sls.Taps | None = None,
    solver: str = "CLARABEL",
    certify: bool = True,
) -> Design:
    """Solve one controller's problem and certify its taps (infeasible and failed solves are
    returned, not raised); ``certify=False`` only measures them (a ``reference`` body).
    ``relaxed`` instead of ``certified`` when the premise does not hold on all the training
    data."""
    sol = sls.solve(r.model, structure, r.values(nominal), solver=solver)
    if sol.taps is None:
        return Design(structure, sol)
    shape = replace(r.shape, gate=structure.gate)
    if certify:
        holds = r.premise is None or r.premise.holds
        body = check(
            sol.taps, r.model, r.numbers, shape, solver_status=sol.status, premise_holds=holds
        )
    else:
        body = check(sol.taps, r.model, r.numbers, shape, reference=True)
    cost = sls.cost_value(
        structure.norm, sol.taps, r.model, sls.psd_sqrt(r.Q), sls.psd_sqrt(r.R), r.numbers.eps_w,
        r.numbers.eps, nominal if cost_of(structure.cost).imitates else None,
    )  # fmt: skip
    return Design(structure, sol, body, cost)


@dataclass(frozen=True)
class Built:
    """One synthesized (or reference) controller with its certificate, ready to write."""

    name: str
    controller: Controller
    certificate: Certificate
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def status(self) -> Status:
        return self.certificate.status

    @property
    def taps(self) -> sls.Taps:
        return self.controller.taps


def _built(
    name: str, ctrl: Controller, body: CertificateBody, setting: dict[str, Any],
    timings: dict[str, float],
) -> Built:  # fmt: skip
    premise = setting.get("premise")
    if body.status_reason and premise is not None and premise.S.violated is None:
        others = [e for k, e in premise.entries().items() if k != "S"]
        reason = body.status_reason
        if premise.n_excluded == 0 and all(e.violated == 0.0 for e in others):
            reason = reason.replace("; " + PREMISE_VIOLATED, "")  # nothing violated: untested
        body = body.model_copy(update={"status_reason": reason + "; " + S_UNTESTED})
    if body.status_reason and premise is not None and premise.eps_w_source == RESIDUAL:
        body = body.model_copy(update={"status_reason": body.status_reason + "; " + NO_INPUTS})
    cert = Certificate.of(body, **setting, controller_sha256=ctrl.sha256())
    return Built(name, ctrl, cert, timings)


S_UNTESTED = (
    "S cannot be tested: no two training flights share an environment (leave-one-flight-out "
    "needs a second flight of the same room and frame), so its value is assumed; certifiable "
    "with a second flight there"
)
NO_INPUTS = (
    "eps_w cannot be measured: the flights logged no inputs, and the input-free residual is a "
    "lower bound on any controller's disturbance; certifiable with the commands flown logged "
    "(qsls fit --inputs) on flights this controller flies (qsls calibrate)"
)


def certified_controller(
    name: str, d: Design, r: Resolved, *, extra: dict[str, Any] | None = None
) -> Built:
    """The controller of a solved :class:`Design` with its certificate."""
    sol, structure = d.solution, d.structure
    assert sol.taps is not None and d.body is not None
    setting = {
        "controller": name,
        "robust": structure.robust,
        "norm": structure.norm,
        "cost": structure.cost,
        "cost_value": d.cost_value,
        "objective": sol.objective,
        "strictly_proper": structure.strictly_proper,
        "T": structure.T,
        **r.record(),
        "gate": r.numbers.gate
        if structure.gate
        else None,  # only a gated design reads through the gate
        "tested_range": r.premise.tested_range if r.premise else None,
        "solver_status": sol.solver_status,
        "dt": r.model.dt,
        "mass": r.model.mass,
        "Q": r.Q.tolist(),
        "R": r.R.tolist(),
        **(extra or {}),
        "premise": r.premise,
    }
    timings = {"build_time_s": sol.build_time_s, "solve_time_s": sol.solve_time_s}
    return _built(name, Controller(sol.taps, r.model), d.body, setting, timings)


def pd_controller(r: Resolved, gains: PDGains, T: int, extra: dict[str, Any]) -> Built:
    """The PD reference: its responses truncated to ``T`` taps are stored, but its norms and
    guarantee numbers are the true closed loop's (:func:`nominal.static_gain_norms`), never the
    truncated ones, which underestimate them."""
    K, taps = pd_responses(r.model, gains, T)
    body = certify(taps, r.model, r.numbers, r.shape, reference=True)
    norms = static_gain_norms(r.model, K, T)
    # weighted norms of the closed loop bounded through its unweighted ones:
    # ||W_x Phi W_e^-1|| <= max w_x ||Phi|| max 1/w_e, and G_m <= max w_x ||Phi_xy||
    wx, we = max(r.shape.state_scale), 1.0 / min(r.shape.error_scale)
    nxy = norms["phi_xy"].value
    true = Norms(
        N=wx * nxy * we, N_w=wx * norms["phi_xx_h"].value, G_m=wx * nxy if r.numbers.m > 0 else 0.0
    )
    true_norms = {f"norm_{k}": n.value for k, n in norms.items()}
    body = body.model_copy(update=true_norms | guarantee_fields(r.numbers, true))
    setting = {
        "controller": "pd",
        "robust": False,
        "norm": None,
        "cost": None,
        "strictly_proper": False,
        "T": T,
        **r.record(),
        "gate": None,
        "closed_loop_norms": norms,
        "closed_loop_spectral_radius": spectral_radius(r.model, K),
        "kp": list(gains.kp),
        "kd": list(gains.kd),
        "dt": r.model.dt,
        "mass": r.model.mass,
        **extra,
    }
    return _built("pd", Controller(taps, r.model, "static_gain", K), body, setting, {})


def nominal_from_folder(path: Path, T: int) -> sls.Taps:
    """The responses of the controller in ``path``, truncated (or padded) to ``T`` taps."""
    if not (Path(path) / CONTROLLER_FILE).is_file():
        raise InputError(
            f"imitate: {path} has no {CONTROLLER_FILE}; give pd, l1_nominal or a controller folder"
        )
    return Controller.load(Path(path)).taps.truncated(T)


IMITATE_NAMED = ("pd", "l1_nominal", "h2_nominal")
"""Imitation targets synthesized with the controllers; any other ``imitate`` is a folder."""


def imitation_target(
    target: str, T: int, done: Mapping[str, sls.Taps], folder: sls.Taps | None = None
) -> sls.Taps:
    """The responses an imitation controller imitates: the PD reference's or a nominal
    controller's among the responses already ``done`` (by name), or ``folder`` (a controller
    folder's, read by the stage)."""
    if target == "pd":
        return done["pd"]
    if target in done:
        return done[target].truncated(T)
    if target in IMITATE_NAMED:
        raise InputError(f"imitate: {target} is not synthesized by this configuration")
    if folder is None:
        raise InputError(f"imitate: {target}: the controller folder was not read")
    return folder


# --------------------------------------------------------------------------- synth
@dataclass(frozen=True)
class Synthesized:
    """Every controller of one configuration with its certificate (:func:`synthesize`), in
    memory; ``qsls synth`` writes it as one folder per controller."""

    resolved: Resolved
    controllers: dict[str, Built]
    paper: Any = None
    """The paper mode's :class:`~qsls.pipeline.control.papermode.PaperChoice`, if asked."""

    def certificates(self) -> dict[str, Certificate]:
        return {n: c.certificate for n, c in self.controllers.items()}

    def statuses(self) -> dict[str, Status]:
        return {n: c.status for n, c in self.controllers.items()}


@dataclass(frozen=True)
class SynthResult:
    out: Path
    controllers: dict[str, Status]  # name -> status
    certificates: dict[str, Certificate] = field(repr=False)

    def summary(self) -> dict[str, Any]:
        out: dict[str, Any] = {"out": self.out.as_posix()}
        for name, cert in self.certificates.items():
            out[name] = (
                f"{cert.status}; N = {cert.norm_N:.4g}, margin = {cert.margin:.3g}, "
                f"rho* = {cert.rho_star:.4g}"
            )
            if cert.tested_range is not None:
                out[name] += f" (premise tested to {cert.tested_range:.3g})"
            out[name] += f", dense error <= {cert.gamma:.4g}"
            if cert.status == RELAXED and cert.premise is not None:
                out[name] += "; " + cert.premise.shares()
        return out


def controller_plan(opts: SynthOptions) -> list[tuple[str, sls.Structure]]:
    """``(name, structure)`` of every synthesized controller, in solve order."""
    T, sp_ = opts.T, opts.strictly_proper
    if opts.controllers == "single":
        rob = "robust" if opts.robust else "nominal"
        name = f"{opts.norm}_{rob}" + ("_imitation" if opts.cost == "imitation" else "")
        return [(name, sls.Structure(T, cast(sls.Norm, opts.norm), opts.cost, opts.robust, sp_))]
    norms: list[sls.Norm] = ["l1", "h2"] if opts.norm == "both" else [opts.norm]
    plan = []
    for n in norms:
        plan += [
            (f"{n}_nominal", sls.Structure(T, n, "qr", False, sp_)),
            (f"{n}_robust", sls.Structure(T, n, "qr", True, sp_)),
            (f"{n}_robust_imitation", sls.Structure(T, n, "imitation", True, sp_)),
        ]
    return plan


LARGE_T = 100  # horizons from here on solve in tens of seconds to minutes per problem


def warn_size(T: int, problems: int, progress: Progress) -> None:
    """A line before a long solve: the FIR problem grows like T (its variables) and its
    interior-point solve faster than that."""
    if T < LARGE_T:
        return
    n_vars = (T + 1) * (NX + NU) * (NX + NX)  # Phi_xx, Phi_ux, Phi_xy, Phi_uy taps
    progress.note(
        f"T = {T}: about {n_vars:,} variables per problem, {problems} problem"
        f"{'s' if problems != 1 else ''}; expect minutes (T = 20 solves in about a second)"
    )


def synthesize(
    model: ErrorModel | None,
    training: TrainingStates | None,
    options: SynthOptions,
    *,
    error_model_sha256: str | None = None,
    imitate: sls.Taps | None = None,
    progress: Progress = NULL_PROGRESS,
) -> Synthesized:
    """The controllers of ``options`` with their certificates (module docstring), from an
    error model and its training data in memory (both optional: numbers alone are a premise
    no data tested). No file is read or written; ``imitate`` is the target's responses when
    ``options.imitate`` names a controller folder. Raises :class:`InfeasibleError` with a
    diagnosis when a robust problem is infeasible."""
    r = resolve(options, model, training)
    if r.premise is not None:
        refuse_empty(r.premise)
    plan = [(n, r.structure(st.T, st.norm, st.cost, st.robust, st.strictly_proper))
            for n, st in controller_plan(options)]  # fmt: skip
    # the error model by its hash only: a path would differ between two folders of one run
    base_extra = {"error_model": None, "error_model_sha256": error_model_sha256,
                  "solver": options.solver}  # fmt: skip
    if (
        any(s.robust for _, s in plan)
        and necessary_condition(r.numbers, r.shape.state_scale, r.shape.error_scale) >= 1.0
    ):
        d = diagnose(r, options.T, options.strictly_proper, options.solver)
        raise InfeasibleError(diagnosis_message(d), d)
    warn_size(options.T, len(plan), progress)
    progress.start("synth", total=len(plan) + 1)
    ctrls: dict[str, Built] = {}
    ctrls["pd"] = pd_controller(r, options.pd, options.T, {**base_extra, "premise": r.premise})
    progress.advance()
    for name, st in plan:
        nominal = None
        extra = dict(base_extra)
        if cost_of(st.cost).imitates:
            done = {n: c.taps for n, c in ctrls.items()}
            nominal = imitation_target(options.imitate, options.T, done, imitate)
            extra["imitate"] = options.imitate
        if options.T >= LARGE_T:
            progress.note(f"solving {name} (T = {options.T}) ...")
        dsg = design(r, st, nominal=nominal, solver=options.solver)
        if dsg.solution.status == "infeasible":
            d = diagnose(r, options.T, options.strictly_proper, options.solver)
            d["controller"] = name
            raise InfeasibleError(f"{name}: " + diagnosis_message(d), d)
        if dsg.solution.status == "error" or dsg.body is None:
            raise SolverError(
                f"{name}: the solver failed ({dsg.solution.solver_status}); nothing was certified"
            )
        ctrls[name] = certified_controller(name, dsg, r, extra=extra)
        progress.advance()
    choice = None
    if options.paper_mode is not None:
        from qsls.pipeline.control.papermode import (
            paper_controllers,  # deferred: import cycle (papermode builds on this module)
        )

        done = {n: c.taps for n, c in ctrls.items()}
        choice, paper = paper_controllers(options, model, training, done, base_extra, imitate)
        ctrls.update(paper)
    progress.finish()
    return Synthesized(r, ctrls, choice)


def synth(
    error_model: Path | None,
    options: SynthOptions,
    out: Path,
    *,
    force: bool = False,
    progress: Progress = NULL_PROGRESS,
) -> SynthResult:
    """The stage: read the error model and its training states, :func:`synthesize`, write one
    folder per controller (``controller.npz``, ``certificate.yaml``) and the manifest."""
    check_output(out, force, [error_model] if error_model is not None else [])
    mi = read_model(error_model)
    folder = None
    if options.imitate not in IMITATE_NAMED and any(
        cost_of(st.cost).imitates for _, st in controller_plan(options)
    ):
        folder = nominal_from_folder(Path(options.imitate), options.T)
    result = synthesize(
        mi.model, mi.training, options, error_model_sha256=mi.sha256, imitate=folder,
        progress=progress,
    )  # fmt: skip
    ctrls = result.controllers
    with StageWriter(out, "synth", options=options, inputs=mi.inputs, force=force) as w:
        for name, c in ctrls.items():
            w.write_bytes(f"{name}/{CONTROLLER_FILE}", c.controller.to_bytes())
            w.write_text(f"{name}/{CERTIFICATE_FILE}", c.certificate.to_yaml())
        w.results["controllers"] = result.statuses()
        w.results["timings"] = {n: c.timings for n, c in ctrls.items() if c.timings}
        w.results["error_model_sha256"] = mi.sha256
        if result.paper is not None:
            w.results["paper_mode"] = result.paper.record()
    return SynthResult(Path(out), result.statuses(), result.certificates())
