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
:func:`qsls.pipeline.control.guarantee.min_norm_bound`) is checked, and an infeasible robust
problem is diagnosed: that condition, the smallest achievable ``||Phi_xy||`` at this ``T`` and
the largest feasible ``S`` (:func:`max_feasible_s`). The stage still writes every controller
that is feasible (the PD, the nominal ones: they need no premise) and then raises
:class:`InfeasibleError` (exit 3) naming the infeasible ones and what it wrote
(docs/synthesis.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from qsls.pipeline.control import sls
from qsls.pipeline.control.artifacts import CERTIFICATE_FILE, CONTROLLER_FILE, Certificate
from qsls.pipeline.control.design import IMITATE_NAMED as IMITATE_NAMED
from qsls.pipeline.control.design import NO_INPUTS as NO_INPUTS
from qsls.pipeline.control.design import S_UNTESTED as S_UNTESTED
from qsls.pipeline.control.design import (
    Built,
    controller_plan,
    imitation_target,
    nominal_from_folder,
    pd_controller,
)
from qsls.pipeline.control.design import Design as Design
from qsls.pipeline.control.design import certified_controller as certified_controller
from qsls.pipeline.control.design import design as design
from qsls.pipeline.control.feasibility import MaxFeasibleSResult as MaxFeasibleSResult
from qsls.pipeline.control.feasibility import diagnose, diagnosis_message
from qsls.pipeline.control.feasibility import max_feasible_s as max_feasible_s
from qsls.pipeline.control.guarantee import necessary_condition
from qsls.pipeline.control.options import ProblemOptions as ProblemOptions
from qsls.pipeline.control.options import SynthOptions
from qsls.pipeline.control.papermode import PaperChoice, paper_controllers
from qsls.pipeline.control.problem import Resolved, resolve
from qsls.pipeline.control.status import RELAXED, Status
from qsls.pipeline.core.artifacts import StageWriter, check_output
from qsls.pipeline.core.errors import InfeasibleError, SolverError
from qsls.pipeline.core.plant import NU, NX
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.premise.choose import ModelInput, read_model
from qsls.pipeline.premise.record import refuse_empty


# --------------------------------------------------------------------------- synth
@dataclass(frozen=True)
class Synthesized:
    """Every controller of one configuration with its certificate (:func:`synthesize`), in
    memory; ``qsls synth`` writes it as one folder per controller."""

    resolved: Resolved
    controllers: dict[str, Built]
    paper: PaperChoice | None = None
    """The paper mode's choice of S, if asked."""
    infeasible: dict[str, InfeasibleError] = field(default_factory=dict)
    """The robust controllers whose problem is infeasible, each with its diagnosis (only with
    ``partial``: :func:`synthesize` raises the first otherwise)."""

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
    source: ModelInput,
    options: SynthOptions,
    *,
    imitate: sls.Taps | None = None,
    progress: Progress = NULL_PROGRESS,
    partial: bool = False,
) -> Synthesized:
    """The controllers of ``options`` with their certificates (module docstring), from an
    error model and its training data in memory (``source``, :func:`read_model`; both
    optional: numbers alone are a premise no data tested). No file is read or written; ``imitate`` is the target's responses when
    ``options.imitate`` names a controller folder. Raises :class:`InfeasibleError` with a
    diagnosis when a robust problem is infeasible; with ``partial`` the feasible controllers
    are returned and the infeasible ones listed in ``infeasible`` instead."""
    r = resolve(options, source)
    if r.premise is not None:
        refuse_empty(r.premise)
    plan = [(n, r.structure(st.T, st.norm, st.cost, st.robust, st.strictly_proper))
            for n, st in controller_plan(options)]  # fmt: skip
    # the error model by its hash only: a path would differ between two folders of one run
    base_extra = {"error_model": None, "error_model_sha256": source.sha256,
                  "solver": options.solver}  # fmt: skip
    infeasible: dict[str, InfeasibleError] = {}
    diagnosis: dict[str, Any] = {}

    def refuse(name: str, *, necessary: bool = False) -> None:
        if not diagnosis:  # one diagnosis of the setting (a bisection on S): computed once
            diagnosis.update(diagnose(r, options.T, options.strictly_proper, options.solver))
        text = diagnosis_message(diagnosis)
        err = InfeasibleError(
            text if necessary and not partial else f"{name}: {text}",
            {**diagnosis, "controller": name},
        )
        if not partial:
            raise err
        infeasible[name] = err

    if (
        any(s.robust for _, s in plan)
        and necessary_condition(r.numbers, r.shape.state_scale, r.shape.error_scale) >= 1.0
    ):
        for name, st in plan:
            if st.robust:
                refuse(name, necessary=True)
        plan = [(n, st) for n, st in plan if not st.robust]
    warn_size(options.T, len(plan), progress)
    progress.start("synth", total=len(plan) + 1)
    ctrls: dict[str, Built] = {}
    ctrls["pd"] = pd_controller(r, options.pd, options.T, {**base_extra, "premise": r.premise})
    progress.advance()
    for name, st in plan:
        nominal = None
        extra = dict(base_extra)
        if st.cost.imitates:
            done = {n: c.taps for n, c in ctrls.items()}
            nominal = imitation_target(options.imitate, options.T, done, imitate)
            extra["imitate"] = options.imitate
        if options.T >= LARGE_T:
            progress.note(f"solving {name} (T = {options.T}) ...")
        dsg = design(r, st, nominal=nominal, solver=options.solver)
        if dsg.solution.status == "infeasible":
            refuse(name)
            progress.advance()
            continue
        if dsg.solution.status == "error" or dsg.body is None:
            raise SolverError(
                f"{name}: the solver failed ({dsg.solution.solver_status}); nothing was certified"
            )
        ctrls[name] = certified_controller(name, dsg, r, extra=extra)
        progress.advance()
    choice = None
    if options.paper_mode is not None:
        done = {n: c.taps for n, c in ctrls.items()}
        choice, paper = paper_controllers(options, source, done, base_extra, imitate)
        ctrls.update(paper)
    progress.finish()
    return Synthesized(r, ctrls, choice, infeasible)


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
        st.cost.imitates for _, st in controller_plan(options)
    ):
        folder = nominal_from_folder(Path(options.imitate), options.T)
    result = synthesize(mi, options, imitate=folder, progress=progress, partial=True)
    ctrls = result.controllers
    with StageWriter(out, "synth", options=options, inputs=mi.inputs, force=force) as w:
        w.results["infeasible"] = {n: str(e) for n, e in result.infeasible.items()}
        for name, c in ctrls.items():
            w.write_bytes(f"{name}/{CONTROLLER_FILE}", c.controller.to_bytes())
            w.write_text(f"{name}/{CERTIFICATE_FILE}", c.certificate.to_yaml())
        w.results["controllers"] = result.statuses()
        w.results["timings"] = {n: c.timings for n, c in ctrls.items() if c.timings}
        w.results["error_model_sha256"] = mi.sha256
        if result.paper is not None:
            w.results["paper_mode"] = result.paper.record()
    if result.infeasible:
        raise infeasible_error(result.infeasible, list(ctrls), Path(out))
    return SynthResult(Path(out), result.statuses(), result.certificates())


def infeasible_error(
    infeasible: dict[str, InfeasibleError], written: list[str], out: Path
) -> InfeasibleError:
    """One error for every infeasible robust controller (they share the diagnosis of the
    setting when the necessary condition fails), naming the feasible ones written."""
    first = next(iter(infeasible.values()))
    names = ", ".join(infeasible)
    return InfeasibleError(
        f"{names}: {diagnosis_message(first.diagnosis)}; written to {out}: "
        f"{', '.join(written)} (feasible; the infeasible ones are listed in its manifest)",
        {**first.diagnosis, "controller": names, "written": written},
    )
