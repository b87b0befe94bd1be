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

Infeasible is an answer: before solving, the necessary condition ``S + eps_e / r < 1``
(``||Phi_xy|| >= 1`` for this plant) is checked, and an infeasible robust problem raises
:class:`InfeasibleError` (exit 3) with a diagnosis: that condition, the smallest achievable
``||Phi_xy||`` at this ``T`` and the largest feasible ``S`` (:func:`max_feasible_s`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, cast

import numpy as np

from qsls.pipeline.control import sls
from qsls.pipeline.control.artifacts import (
    CERTIFICATE_FILE,
    CONTROLLER_FILE,
    Certificate,
    CertificateBody,
    Controller,
)
from qsls.pipeline.control.guarantee import PremiseNumbers
from qsls.pipeline.control.options import ProblemOptions, SynthOptions
from qsls.pipeline.control.pdgain import PDGains
from qsls.pipeline.control.premise import Measured, Premise, TrainingStates, training_beside
from qsls.pipeline.control.status import RELAXED, Status
from qsls.pipeline.core.artifacts import StageWriter, sha256_file
from qsls.pipeline.core.errors import InfeasibleError, InputError, SolverError
from qsls.pipeline.core.plant import (
    NU,
    NX,
    LinearModel,
    quadrotor_model,
)
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.errormodel.model import (
    TRAINING_FILE,
    ErrorModel,
    error_model_file,
    load_error_model,
)


# --------------------------------------------------------------------------- resolution
@dataclass(frozen=True)
class Resolved:
    """A problem's numbers, names resolved against the error model and its training data,
    with the premise they form (:mod:`qsls.pipeline.control.premise`)."""

    model: LinearModel
    Q: np.ndarray
    R: np.ndarray
    S: float
    eps_e: float
    radius: float
    delta: float
    R0: float
    eps_w: float
    m: int = 0
    eps_o: float = 0.0
    shape: sls.Shape = field(default_factory=sls.Shape)
    premise: Premise | None = None
    gate: float | None = None

    def values(self, nominal: sls.Taps | None = None) -> sls.Values:
        return sls.Values(
            Q=self.Q, R=self.R, eps_w=self.eps_w, eps_e=self.eps_e, S=self.S,
            radius=self.radius, delta=self.delta, nominal=nominal, eps_o=self.eps_o,
            gate=self.gate,
        )  # fmt: skip

    def numbers(self) -> PremiseNumbers:
        return PremiseNumbers(
            eps=self.eps_e, S=self.S, radius=self.radius, eps_w=self.eps_w, delta=self.delta,
            eps_o=self.eps_o, m=self.m, R0=self.R0, gate=self.gate,
        )  # fmt: skip

    def structure(self, T: int, norm: sls.Norm, cost: Any, robust: bool, sp_: bool) -> sls.Structure:
        sh = self.shape
        return sls.Structure(
            T, norm, cost, robust, sp_, state_scale=sh.state_scale, error_scale=sh.error_scale,
            measure=sh.measure, m=sh.m, gate=sh.gate and robust,
        )  # fmt: skip

    def record(self) -> dict[str, Any]:
        return {
            "S": self.S, "eps_e": self.eps_e, "radius": self.radius, "delta": self.delta,
            "eps_w": self.eps_w, "R0": self.R0, "m": self.m, "eps_o": self.eps_o,
            "measure": self.shape.measure, "gate": self.gate,
        }  # fmt: skip


def _how(value: Any) -> str:
    return "number" if isinstance(value, int | float) else str(value)


def _needs_model(what: str, v: Any, em: ErrorModel | None) -> ErrorModel:
    if em is None:
        raise InputError(
            f"{what} = '{v}' names a number of an error model, but none was given; "
            "pass --model or give a number"
        )
    return em


def _eps(opts: ProblemOptions, em: ErrorModel | None, meas: Measured | None, trivial: bool) -> float:
    v = opts.eps_e
    if isinstance(v, int | float):
        return float(v)
    em = _needs_model("eps_e", v, em)
    if meas is not None:
        key = str(v).strip()
        if key == "max":
            return meas.eps
        if key.startswith("p"):
            try:
                return float(np.percentile(meas.dense, float(key[1:])))
            except ValueError:
                pass
    elif not trivial:
        raise InputError(
            "eps_e: with measure, beta or error_scale set, the dense bound is measured on the "
            "training states, but the error model has none beside it; pass the fit folder"
        )
    return em.resolve_eps_e(v)


def _slope(opts: ProblemOptions, em: ErrorModel | None, meas: Measured | None) -> float:
    v = opts.S
    if isinstance(v, int | float):
        return float(v)
    em = _needs_model("S", v, em)
    if str(v).strip() != "lofo":
        return em.resolve_s(v)
    if meas is None:
        raise InputError(
            "S = lofo is measured on the training states beside the error model, which are "
            "missing; pass the fit folder, or give S as a number"
        )
    if math.isnan(meas.slope.S):
        raise InputError(
            "S = lofo leaves one training flight out at a time and needs at least two; fit on "
            "more flights, or give S as a number (the premise is then untested: relaxed)"
        )
    if not math.isfinite(meas.slope.S):
        raise InputError(
            "S = lofo is infinite: a left-out sample exceeds the other flights' largest error at "
            "distance 0 from them; give S as a number (relaxed) or raise beta / error_scale"
        )
    return meas.slope.S


def _disturbance(
    opts: ProblemOptions, em: ErrorModel | None, meas: Measured | None
) -> tuple[float, str]:
    """``eps_w``: a number, or the training flights' realized disturbance ``||H^-1 w_k||``."""
    v = opts.eps_w
    if isinstance(v, int | float):
        return float(v), "number"
    name = "max" if v is None else str(v).strip()
    if meas is not None and meas.w_norm is not None:
        q = None if name == "max" else _percentile(name, "eps_w")
        w = meas.eps_w(q)
        if w is not None:
            return w, name
    if v is None and (em is None or em.disturbance is None):
        return 0.01, "default (assumed, not measured)"
    if em is None:
        raise InputError(f"eps_w = '{v}' needs an error model; pass --model or give a number")
    if opts.H is not None:
        raise InputError(
            "eps_w with H: the disturbance is measured as ||H^-1 w|| on the training states, "
            "which are missing beside the error model; pass the fit folder or give a number"
        )
    return em.resolve_eps_w(name), name


def _percentile(name: str, what: str) -> float:
    try:
        if name.startswith("p"):
            return float(name[1:])
    except ValueError:
        pass
    raise InputError(f"{what} = '{name}': use max, pNN or a number")


def resolve(
    opts: ProblemOptions, em: ErrorModel | None, training: TrainingStates | None = None
) -> Resolved:
    """Numbers for every setting, names (``max``, ``lofo``, ``p95``...) looked up on the error
    model and its training states, and the premise they form with its violated shares (pure:
    no file is read)."""
    from qsls.pipeline.control.premise import Chosen, Spec, premise_record

    if opts.radius is not None:
        radius = float(opts.radius)
    elif em is not None:
        radius = float(em.radius)
    else:
        raise InputError("radius: give a number (no error model to take it from)")
    if opts.H is not None and abs(np.linalg.det(np.asarray(opts.H))) < 1e-12:
        raise InputError("H must be invertible: eps_w bounds ||H^-1 w|| of the realized disturbance")
    state_scale = tuple(em.state_scale) if em is not None else (1.0,) * 6
    spec = Spec(
        measure=opts.measure, beta=math.inf if opts.beta is None else float(opts.beta),
        state_scale=state_scale, error_scale=tuple(opts.error_scale), radius=radius,
        window=opts.T, risk=opts.outlier_risk,
        H=None if opts.H is None else tuple(tuple(r) for r in opts.H),
    )  # fmt: skip
    trivial = opts.measure == "full" and opts.beta is None and all(w == 1.0 for w in opts.error_scale)
    meas = training.measured(spec) if em is not None and training is not None else None
    where = None
    if em is not None:
        where = (
            training.source if training is not None
            else f"no {TRAINING_FILE} beside the error model: shares not computed"
        )  # fmt: skip
    eps_e = _eps(opts, em, meas, trivial)
    S = _slope(opts, em, meas)
    for name, val in (("S", S), ("eps_e", eps_e)):
        if not (math.isfinite(val) and val >= 0):
            raise InputError(f"{name} = '{getattr(opts, name)}' is {val}; need a finite number >= 0")
    eps_w, how_w = _disturbance(opts, em, meas)
    outlier_ch = opts.measure == "full" and opts.beta is not None
    if not outlier_ch:
        m = 0
    elif opts.m == "auto":
        m = meas.outliers.m if meas is not None else 0
    else:
        m = int(opts.m)
    if opts.gate is not None and not outlier_ch:
        raise InputError("gate: a velocity gate needs measure: full and beta (it bounds outliers)")
    if opts.gate is not None and opts.eps_o is not None:
        raise InputError("give gate or eps_o, not both: the gate sets eps_o = 2 gate - beta")
    if outlier_ch and opts.eps_o is None and opts.gate is None:
        raise InputError(
            "beta clips the velocity errors, so what it clips off is an outlier: give eps_o, a "
            "bound on one outlier from the estimator's physics, or a velocity gate (never the "
            "sample maximum)"
        )
    if opts.gate is not None:
        assert opts.beta is not None
        if 2 * opts.gate <= opts.beta:
            raise InputError(f"gate {opts.gate:g} must exceed beta / 2 = {opts.beta / 2:g}")
        eps_o = 2 * opts.gate - opts.beta
    else:
        eps_o = float(opts.eps_o or 0.0) if outlier_ch else 0.0
    if opts.delta is None:
        delta = float(em.delta) if em is not None else 0.0
    elif isinstance(opts.delta, int | float):
        delta = float(opts.delta)
    elif opts.delta == "delta" and em is not None:
        delta = float(em.delta)
    else:
        raise InputError(
            f"delta = '{opts.delta}': give a number (or omit it to use the error model's)"
        )
    # R0: the error bound in use unless set, so that gamma_strict <= gamma
    R0 = eps_e if opts.R0 is None else (
        float(opts.R0) if isinstance(opts.R0, int | float) else em.resolve_eps_e(opts.R0)  # type: ignore[union-attr]
    )  # fmt: skip
    from_em = "error model" if em is not None else "default"
    how = {
        "eps_e": _how(opts.eps_e), "S": _how(opts.S), "eps_w": how_w,
        "m": "binomial" if opts.m == "auto" else "number",
        "eps_o": "gate (2V - beta)" if opts.gate is not None else "given",
        "r": from_em if opts.radius is None else "number",
        "Delta": from_em if opts.delta is None else _how(opts.delta),
    }  # fmt: skip
    chosen = Chosen(eps_e, S, radius, delta, eps_w, m, eps_o, how, opts.gate)
    premise = premise_record(chosen, meas, em, where)
    H = None if opts.H is None else np.asarray(opts.H)
    model = quadrotor_model(dt=opts.dt, mass=opts.mass, H=H)
    shape = sls.Shape(state_scale, tuple(opts.error_scale), opts.measure, m, opts.gate is not None)
    return Resolved(
        model, np.asarray(opts.Q), np.asarray(opts.R), S, eps_e, radius, delta, R0, eps_w,
        m, eps_o, shape, premise, opts.gate,
    )  # fmt: skip


@dataclass(frozen=True)
class ModelInput:
    """What a stage reads for its error model: the model, the sha256 of ``error_model.yaml``,
    the file, and the training states beside it (each None when absent)."""

    model: ErrorModel | None = None
    sha256: str | None = None
    file: Path | None = None
    training: TrainingStates | None = None

    @property
    def inputs(self) -> list[Path]:
        return [self.file] if self.file is not None else []


def read_model(path: Path | None) -> ModelInput:
    """The error model of ``path`` (a fit folder or its ``error_model.yaml``) and the training
    states beside it, read once; empty without a path."""
    if path is None:
        return ModelInput()
    f = error_model_file(path)
    return ModelInput(load_error_model(f), sha256_file(f), f, training_beside(f))


# --------------------------------------------------------------------------- diagnosis
def diagnose(
    r: Resolved, T: int, strictly_proper: bool, solver: str = "CLARABEL"
) -> dict[str, Any]:
    """Why a robust problem is infeasible: the necessary condition, the smallest
    achievable ``N`` at ``T`` and the largest feasible ``S``."""
    from qsls.pipeline.control.guarantee import necessary_condition

    nec = necessary_condition(r.numbers())
    min_xy = sls.min_phi_xy(r.model, T, strictly_proper=strictly_proper, solver=solver, shape=r.shape)
    ms = sls.max_feasible_s(
        r.model, T, eps_e=r.eps_e, radius=r.radius, eps_w=r.eps_w, delta=r.delta,
        eps_o=r.eps_o, gate=r.gate, strictly_proper=strictly_proper, solver=solver,
        shape=r.shape,
    )  # fmt: skip
    return {
        "S": r.S,
        "eps_e": r.eps_e,
        "radius": r.radius,
        "S_plus_eps_e_over_r": nec,
        "necessary_condition_holds": bool(nec < 1.0),
        "min_norm_phi_xy": min_xy,
        "max_feasible_S": ms.s_max,
        "T": T,
    }


def diagnosis_message(d: dict[str, Any]) -> str:
    """One line: what fails, and what could help (a radius cannot help when ``S >= 1``)."""
    parts = []
    if not d["necessary_condition_holds"]:
        parts.append(
            f"S + eps_e/r = {d['S_plus_eps_e_over_r']:.4g} >= 1 fails the necessary condition "
            "S + eps_e/r < 1 (||Phi_xy|| >= 1 for this plant)"
        )
    else:
        parts.append(
            f"the necessary condition S + eps_e/r < 1 holds ({d['S_plus_eps_e_over_r']:.4g})"
        )
    parts.append(f"the smallest achievable N = ||W_x Phi_xy W_e^-1|| at T={d['T']} is {d['min_norm_phi_xy']:.4g}")
    if d["S"] >= 1.0:
        parts.append(
            f"no radius or horizon can help: S = {d['S']:.4g} >= 1 alone breaks S N < 1; a smaller "
            "S needs a different premise (S = lofo, an error_scale that weights the velocity "
            "errors less, beta with eps_o, or measure: position)"
        )
    if d["max_feasible_S"] >= 0:
        parts.append(
            f"the largest feasible S for this setting is {d['max_feasible_S']:.6g} (S = {d['S']:.4g} given)"
        )
    elif d["S"] < 1.0:
        parts.append(
            "no S >= 0 is feasible for this setting: lower eps_e (beta, error_scale, measure: "
            "position) or Delta (training flights nearer the reference), or raise r or T"
        )
    return "robust synthesis is infeasible: " + "; ".join(parts)


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
    from qsls.pipeline.control.certify import certify as check

    sol = sls.solve(r.model, structure, r.values(nominal), solver=solver)
    if sol.taps is None:
        return Design(structure, sol)
    shape = replace(r.shape, gate=structure.gate)
    if certify:
        holds = r.premise is None or r.premise.holds
        body = check(
            sol.taps, r.model, r.numbers(), shape, solver_status=sol.status, premise_holds=holds
        )
    else:
        body = check(sol.taps, r.model, r.numbers(), shape, reference=True)
    cost = sls.cost_value(
        structure.norm, sol.taps, r.model, sls.psd_sqrt(r.Q), sls.psd_sqrt(r.R), r.eps_w,
        r.eps_e, nominal if structure.cost == "imitation" else None,
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
    cert = Certificate.of(body, **setting, controller_sha256=ctrl.sha256())
    return Built(name, ctrl, cert, timings)


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
        "gate": r.gate if structure.gate else None,  # only a gated design reads through the gate
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
    from qsls.pipeline.control.certify import certify, guarantee_fields
    from qsls.pipeline.control.guarantee import Norms
    from qsls.pipeline.control.nominal import pd_responses, spectral_radius, static_gain_norms

    K, taps = pd_responses(r.model, gains, T)
    body = certify(taps, r.model, r.numbers(), r.shape, reference=True)
    norms = static_gain_norms(r.model, K, T)
    # weighted norms of the closed loop bounded through its unweighted ones:
    # ||W_x Phi W_e^-1|| <= max w_x ||Phi|| max 1/w_e, and G_m <= max w_x ||Phi_xy||
    wx, we = max(r.shape.state_scale), 1.0 / min(r.shape.error_scale)
    nxy = norms["phi_xy"].value
    true = Norms(
        N=wx * nxy * we, N_w=wx * norms["phi_xx_h"].value, G_m=wx * nxy if r.m > 0 else 0.0
    )
    true_norms = {f"norm_{k}": n.value for k, n in norms.items()}
    body = body.model_copy(update=true_norms | guarantee_fields(r.numbers(), true))
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
    target: str, T: int, done: dict[str, Built], folder: sls.Taps | None = None
) -> sls.Taps:
    """The responses an imitation controller imitates: the PD reference or a nominal
    controller among those already ``done``, or ``folder`` (a controller folder's, read by the
    stage)."""
    if target == "pd":
        return done["pd"].taps
    if target in done:
        return done[target].taps.truncated(T)
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
    from qsls.pipeline.control.guarantee import necessary_condition
    from qsls.pipeline.control.premise import refuse_empty

    r = resolve(options, model, training)
    if r.premise is not None:
        refuse_empty(r.premise)
    plan = [(n, r.structure(st.T, st.norm, st.cost, st.robust, st.strictly_proper))
            for n, st in controller_plan(options)]  # fmt: skip
    # the error model by its hash only: a path would differ between two folders of one run
    base_extra = {"error_model": None, "error_model_sha256": error_model_sha256,
                  "solver": options.solver}  # fmt: skip
    if any(s.robust for _, s in plan) and necessary_condition(r.numbers()) >= 1.0:
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
        if st.cost == "imitation":
            nominal = imitation_target(options.imitate, options.T, ctrls, imitate)
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
    progress.finish()
    return Synthesized(r, ctrls)


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
    from qsls.pipeline.core.artifacts import check_output

    check_output(out, force, [error_model] if error_model is not None else [])
    mi = read_model(error_model)
    folder = None
    if options.imitate not in IMITATE_NAMED and any(
        st.cost == "imitation" for _, st in controller_plan(options)
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
    return SynthResult(Path(out), result.statuses(), result.certificates())


# --------------------------------------------------------------------------- max S
@dataclass(frozen=True)
class MaxFeasibleSResult:
    s_max: float
    min_norm_phi_xy: float
    T: int
    eps_e: float
    radius: float
    eps_w: float
    delta: float
    iterations: int

    def summary(self) -> dict[str, Any]:
        return {
            "largest feasible S": self.s_max,
            "T": self.T,
            "eps_e": self.eps_e,
            "radius": self.radius,
            "eps_w": self.eps_w,
            "delta": self.delta,
            "smallest ||Phi_xy|| at T": self.min_norm_phi_xy,
            "Dinkelbach iterations": self.iterations,
        }


def max_feasible_s(error_model: Path | None, options: ProblemOptions) -> MaxFeasibleSResult:
    """The largest S for which the robust problem of ``options`` is feasible under its premise
    (its feasibility does not depend on the cost); see :func:`qsls.pipeline.control.sls.max_feasible_s`."""
    mi = read_model(error_model)
    opts = options.model_copy(update={"S": 0.0})
    r = resolve(opts, mi.model, mi.training)
    ms = sls.max_feasible_s(
        r.model, options.T, eps_e=r.eps_e, radius=r.radius, eps_w=r.eps_w, delta=r.delta,
        eps_o=r.eps_o, gate=r.gate, strictly_proper=options.strictly_proper,
        solver=options.solver, shape=r.shape,
    )  # fmt: skip
    min_xy = sls.min_phi_xy(
        r.model, options.T, strictly_proper=options.strictly_proper, solver=options.solver,
        shape=r.shape,
    )  # fmt: skip
    if not ms.s_max >= 0:
        # at S = 0 the constraint is (eps N + eps_w N_w + Delta + eps_o G_m) / r <= 1, with N
        # at least its minimum at T and N_w >= min w_x (Phi_xx(1) = I)
        lower = (r.eps_e * min_xy + r.eps_w * min(r.shape.state_scale) + r.delta) / r.radius
        raise InfeasibleError(
            f"none feasible: no S >= 0 is feasible at T = {options.T}: even S = 0 needs "
            f"(eps_e N + eps_w N_w + Delta + eps_o G_m) / r < 1, and with eps_e = "
            f"{r.eps_e:.4g}, the smallest N = {min_xy:.4g} at this T, eps_w = "
            f"{r.eps_w:.4g}, Delta = {r.delta:.4g} and r = {r.radius:.4g} it is at least "
            f"{lower:.4g}; lower eps_e (beta, error_scale, measure: position) or Delta, or "
            "raise r or T",
            {"T": options.T, "min_norm_phi_xy": min_xy, "lower_bound_at_S0": lower},
        )
    return MaxFeasibleSResult(
        ms.s_max, min_xy, options.T, r.eps_e, r.radius, r.eps_w, r.delta, ms.iterations
    )
