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

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, cast

import numpy as np
from pydantic import Field, field_validator, model_validator

from qsls.pipeline.control import sls
from qsls.pipeline.control.artifacts import (
    CERTIFICATE_FILE,
    CONTROLLER_FILE,
    Certificate,
    Controller,
)
from qsls.pipeline.control.pdgain import PDGains
from qsls.pipeline.control.plant import (
    NU,
    NX,
    PAPER_DT_S,
    PAPER_MASS_KG,
    LinearModel,
    quadrotor_model,
)
from qsls.pipeline.control.premise import Premise, check_unweighted, premise_of
from qsls.pipeline.core.artifacts import StageWriter, sha256_file
from qsls.pipeline.core.config import Options
from qsls.pipeline.core.errors import InfeasibleError, InputError, SolverError
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.errormodel.model import ErrorModel, error_model_file, load_error_model

Number = float | str


def _matrix(value: Any, n: int, what: str, psd: bool) -> list[list[float]]:
    """A list of ``n`` numbers (diagonal) or an ``n x n`` nested list -> nested list."""
    a = np.asarray(value, dtype=float)
    if a.ndim == 1:
        if a.shape != (n,):
            raise ValueError(
                f"{what} needs {n} diagonal entries or an {n}x{n} matrix, got {a.size}"
            )
        a = np.diag(a)
    if a.shape != (n, n):
        raise ValueError(f"{what} must be {n}x{n}, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{what} has non-finite entries")
    if psd:
        sls.psd_sqrt(a, what)
    return a.tolist()


class ProblemOptions(Options):
    """One synthesis problem's settings (shared by ``synth`` and ``sweep``)."""

    T: int = Field(20, ge=2, le=500, description="FIR horizon (taps 0..T)")
    norm: Literal["l1", "h2"] = "l1"
    cost: Literal["qr", "imitation"] = "qr"
    robust: bool = True
    strictly_proper: bool = False
    Q: list[list[float]] = Field(default_factory=lambda: np.diag([10.0, 10, 10, 1, 1, 1]).tolist())
    R: list[list[float]] = Field(default_factory=lambda: np.diag([1.0, 1, 0.1]).tolist())
    eps_w: float = Field(0.01, ge=0, description="process noise bound ||w|| <= eps_w")
    H: list[list[float]] | None = None
    mass: float = Field(PAPER_MASS_KG, gt=0)
    dt: float = Field(PAPER_DT_S, gt=0)
    S: Number = "max"
    eps_e: Number = "max"
    radius: float | None = Field(None, gt=0, description="default: the error model's radius")
    delta: Number | None = Field(None, description="Delta; default: the error model's delta")
    R0: Number | None = Field(
        None,
        description="R0 for gamma_strict; default: the eps_e in use (so gamma_strict <= gamma)",
    )
    pd: PDGains = PDGains()
    imitate: str = Field(
        "pd", description="imitation target: pd, l1_nominal, h2_nominal or a folder"
    )
    solver: str = "CLARABEL"

    @field_validator("Q", mode="before")
    @classmethod
    def _q(cls, v: Any) -> Any:
        return _matrix(v, NX, "Q", True)

    @field_validator("R", mode="before")
    @classmethod
    def _r(cls, v: Any) -> Any:
        return _matrix(v, NU, "R", True)

    @field_validator("H", mode="before")
    @classmethod
    def _h(cls, v: Any) -> Any:
        return None if v is None else _matrix(v, NX, "H", False)

    @field_validator("S", "eps_e")
    @classmethod
    def _nonneg(cls, v: Any) -> Any:
        if isinstance(v, int | float) and v < 0:
            raise ValueError("must be >= 0")
        return v


class SynthOptions(ProblemOptions):
    """Options of ``qsls synth``."""

    norm: Literal["l1", "h2", "both"] = "l1"  # type: ignore[assignment]
    controllers: Literal["paper", "single"] = "paper"

    @model_validator(mode="after")
    def _single(self) -> SynthOptions:
        if self.controllers == "single" and self.norm == "both":
            raise ValueError("controllers: single needs norm l1 or h2")
        return self


# --------------------------------------------------------------------------- resolution
@dataclass(frozen=True)
class Resolved:
    """A problem's numbers, names resolved against the error model."""

    model: LinearModel
    Q: np.ndarray
    R: np.ndarray
    S: float
    eps_e: float
    radius: float
    delta: float
    R0: float
    eps_w: float

    def values(self, nominal: sls.Taps | None = None) -> sls.Values:
        return sls.Values(
            Q=self.Q, R=self.R, eps_w=self.eps_w, eps_e=self.eps_e, S=self.S,
            radius=self.radius, delta=self.delta, nominal=nominal,
        )  # fmt: skip

    def setting(self) -> Any:
        from qsls.pipeline.control.certify import Setting

        return Setting(self.S, self.eps_e, self.radius, self.eps_w, self.delta, self.R0)

    def record(self) -> dict[str, Any]:
        return {
            "S": self.S, "eps_e": self.eps_e, "radius": self.radius, "delta": self.delta,
            "eps_w": self.eps_w, "R0": self.R0,
        }  # fmt: skip


def _number(value: Number | None, em: ErrorModel | None, what: str, resolver: str) -> float:
    if isinstance(value, int | float):
        return float(value)
    if em is None:
        raise InputError(
            f"{what} = '{value}' names a number of an error model, but none was given; "
            "pass --model or give a number"
        )
    out = getattr(em, resolver)(value)
    if not np.isfinite(out) or out < 0:
        raise InputError(
            f"{what} = '{value}' is {out} in the error model; need a finite number >= 0"
        )
    return out


def resolve(opts: ProblemOptions, em: ErrorModel | None) -> Resolved:
    """Numbers for every setting; error-model names (``max``, ``p95``...) looked up; an error
    model with a weighted state norm refused (:func:`check_unweighted`)."""
    check_unweighted(em)
    S = _number(opts.S, em, "S", "resolve_s")
    eps_e = _number(opts.eps_e, em, "eps_e", "resolve_eps_e")
    if opts.radius is not None:
        radius = float(opts.radius)
    elif em is not None:
        radius = float(em.radius)
    else:
        raise InputError("radius: give a number (no error model to take it from)")
    if radius <= 0:
        raise InputError(f"radius must be > 0, got {radius}")
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
    # R0: the error bound in use unless set, so that gamma_strict <= gamma (DESIGN.md)
    R0 = eps_e if opts.R0 is None else _number(opts.R0, em, "R0", "resolve_eps_e")
    H = None if opts.H is None else np.asarray(opts.H)
    model = quadrotor_model(dt=opts.dt, mass=opts.mass, H=H)
    return Resolved(
        model, np.asarray(opts.Q), np.asarray(opts.R), S, eps_e, radius, delta, R0, opts.eps_w
    )


def read_model(path: Path | None) -> tuple[ErrorModel | None, str | None, Path | None]:
    """``(error model, sha256 of error_model.yaml, file)``; all None without a path."""
    if path is None:
        return None, None, None
    f = error_model_file(path)
    return load_error_model(f), sha256_file(f), f


# --------------------------------------------------------------------------- diagnosis
def diagnose(
    r: Resolved, T: int, strictly_proper: bool, solver: str = "CLARABEL"
) -> dict[str, Any]:
    """Why a robust problem is infeasible: the necessary condition, the smallest
    achievable ``||Phi_xy||`` at ``T`` and the largest feasible ``S``."""
    nec = r.S + r.eps_e / r.radius
    min_xy = sls.min_phi_xy(r.model, T, strictly_proper=strictly_proper, solver=solver)
    ms = sls.max_feasible_s(
        r.model, T, eps_e=r.eps_e, radius=r.radius, eps_w=r.eps_w, delta=r.delta,
        strictly_proper=strictly_proper, solver=solver,
    )  # fmt: skip
    return {
        "S": r.S,
        "S_plus_eps_e_over_r": nec,
        "necessary_condition_holds": bool(nec < 1.0),
        "min_norm_phi_xy": min_xy,
        "max_feasible_S": ms.s_max,
        "T": T,
    }


def diagnosis_message(d: dict[str, Any]) -> str:
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
    parts.append(f"the smallest achievable ||Phi_xy|| at T={d['T']} is {d['min_norm_phi_xy']:.4g}")
    if d["max_feasible_S"] >= 0:
        parts.append(
            f"the largest feasible S for this setting is {d['max_feasible_S']:.6g} (S = {d['S']:.4g} given)"
        )
    else:
        parts.append("no S >= 0 is feasible for this setting (lower eps_e or Delta, raise r or T)")
    return "robust synthesis is infeasible: " + "; ".join(parts)


# --------------------------------------------------------------------------- one controller
@dataclass(frozen=True)
class Built:
    """One synthesized (or reference) controller with its certificate, ready to write."""

    name: str
    controller: Controller
    certificate: Certificate
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def status(self) -> str:
        return self.certificate.status

    @property
    def taps(self) -> sls.Taps:
        return self.controller.taps


def solve_one(
    r: Resolved,
    structure: sls.Structure,
    *,
    nominal: sls.Taps | None = None,
    solver: str = "CLARABEL",
) -> sls.Solution:
    """Solve one controller's problem; infeasible/failed are returned, not raised."""
    return sls.solve(r.model, structure, r.values(nominal), solver=solver)


def _built(name: str, ctrl: Controller, cert: dict[str, Any], timings: dict[str, float]) -> Built:
    cert = {**cert, "controller_sha256": ctrl.sha256()}
    return Built(name, ctrl, Certificate.model_validate(cert), timings)


def certified_controller(
    name: str,
    sol: sls.Solution,
    r: Resolved,
    structure: sls.Structure,
    *,
    extra: dict[str, Any] | None = None,
    nominal: sls.Taps | None = None,
    premise: Premise | None = None,
) -> Built:
    """Certify a solution and assemble its certificate and controller; ``certified_relaxed``
    instead of ``certified`` when the ``premise`` does not hold on all the training data."""
    from qsls.pipeline.control.certify import certify

    assert sol.taps is not None
    holds = premise is None or premise.holds
    status, fields = certify(
        sol.taps, r.model, r.setting(), solver_status=sol.status, premise_holds=holds
    )
    q_half, r_half = sls.psd_sqrt(r.Q), sls.psd_sqrt(r.R)
    cost = sls.cost_value(
        structure.norm, sol.taps, r.model, q_half, r_half, r.eps_w, r.eps_e,
        nominal if structure.cost == "imitation" else None,
    )  # fmt: skip
    cert = {
        "controller": name,
        "status": status,
        "robust": structure.robust,
        "norm": structure.norm,
        "cost": structure.cost,
        "cost_value": cost,
        "objective": sol.objective,
        "strictly_proper": structure.strictly_proper,
        "T": structure.T,
        **r.record(),
        **fields,
        "solver_status": sol.solver_status,
        "dt": r.model.dt,
        "mass": r.model.mass,
        "Q": r.Q.tolist(),
        "R": r.R.tolist(),
        **(extra or {}),
        "premise": premise,
    }
    timings = {"build_time_s": sol.build_time_s, "solve_time_s": sol.solve_time_s}
    return _built(name, Controller(sol.taps, r.model), cert, timings)


def pd_controller(r: Resolved, gains: PDGains, T: int, extra: dict[str, Any]) -> Built:
    """The PD reference: its responses truncated to ``T`` taps are stored, but its norms and
    guarantee numbers are the true closed loop's (:func:`nominal.static_gain_norms`), never the
    truncated ones, which underestimate them."""
    from qsls.pipeline.control.certify import certify, guarantee
    from qsls.pipeline.control.nominal import pd_responses, spectral_radius, static_gain_norms

    K, taps = pd_responses(r.model, gains, T)
    status, fields = certify(taps, r.model, r.setting(), reference=True)
    norms = static_gain_norms(r.model, K, T)
    fields |= {f"norm_{k}": n.value for k, n in norms.items()}
    fields |= guarantee(norms["phi_xy"].value, norms["phi_xx_h"].value, r.setting())
    fields["closed_loop_norms"] = norms
    cert = {
        "controller": "pd",
        "status": status,
        "robust": False,
        "norm": None,
        "cost": None,
        "strictly_proper": False,
        "T": T,
        **r.record(),
        **fields,
        "closed_loop_spectral_radius": spectral_radius(r.model, K),
        "kp": list(gains.kp),
        "kd": list(gains.kd),
        "dt": r.model.dt,
        "mass": r.model.mass,
        **extra,
    }
    return _built("pd", Controller(taps, r.model, "static_gain", K), cert, {})


def nominal_from_folder(path: Path, T: int) -> sls.Taps:
    """The responses of the controller in ``path``, truncated (or padded) to ``T`` taps."""
    if not (Path(path) / CONTROLLER_FILE).is_file():
        raise InputError(
            f"imitate: {path} has no {CONTROLLER_FILE}; give pd, l1_nominal or a controller folder"
        )
    return Controller.load(Path(path)).taps.truncated(T)


# --------------------------------------------------------------------------- synth
@dataclass(frozen=True)
class SynthResult:
    out: Path
    controllers: dict[str, str]  # name -> status
    certificates: dict[str, dict[str, Any]] = field(repr=False)

    def summary(self) -> dict[str, Any]:
        out: dict[str, Any] = {"out": self.out.as_posix()}
        for name, cert in self.certificates.items():
            g = cert.get("gamma")
            out[name] = (
                f"{cert['status']}; ||Phi_xy|| = {cert['norm_phi_xy']:.4g}, "
                f"margin = {cert['margin']:.3g}, gamma = {g:.4g}"
            )
            if cert["status"] == "certified_relaxed" and cert.get("premise"):
                out[name] += "; " + Premise.model_validate(cert["premise"]).shares()
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


def synth(
    error_model: Path | None,
    options: SynthOptions,
    out: Path,
    *,
    force: bool = False,
    progress: Progress = NULL_PROGRESS,
) -> SynthResult:
    """Synthesize, certify and write the controllers of ``options`` (module docstring)."""
    from qsls.pipeline.core.artifacts import check_output

    check_output(out, force, [error_model] if error_model is not None else [])
    em, sha, em_file = read_model(error_model)
    r = resolve(options, em)
    plan = controller_plan(options)
    prem = premise_of(options, r.record(), em, em_file)
    base_extra = {
        "error_model": em_file.as_posix() if em_file else None,
        "error_model_sha256": sha,
        "solver": options.solver,
    }
    if any(s.robust for _, s in plan) and r.S + r.eps_e / r.radius >= 1.0:
        d = diagnose(r, options.T, options.strictly_proper, options.solver)
        raise InfeasibleError(diagnosis_message(d), d)
    warn_size(options.T, len(plan), progress)
    progress.start("synth", total=len(plan) + 1)
    ctrls: dict[str, Built] = {}
    reference = pd_controller(r, options.pd, options.T, {**base_extra, "premise": prem})
    ctrls["pd"] = reference
    progress.advance()
    for name, st in plan:
        nominal = None
        extra = dict(base_extra)
        if st.cost == "imitation":
            target = options.imitate
            if target == "pd":
                nominal = reference.taps
            elif target in ctrls:
                nominal = ctrls[target].taps.truncated(options.T)
            elif target in ("l1_nominal", "h2_nominal"):
                raise InputError(f"imitate: {target} is not synthesized by this configuration")
            else:
                nominal = nominal_from_folder(Path(target), options.T)
            extra["imitate"] = target
        if options.T >= LARGE_T:
            progress.note(f"solving {name} (T = {options.T}) ...")
        sol = solve_one(r, st, nominal=nominal, solver=options.solver)
        if sol.status == "infeasible":
            d = diagnose(r, options.T, options.strictly_proper, options.solver)
            d["controller"] = name
            raise InfeasibleError(f"{name}: " + diagnosis_message(d), d)
        if sol.status == "error" or sol.taps is None:
            raise SolverError(
                f"{name}: the solver failed ({sol.solver_status}); nothing was certified"
            )
        ctrls[name] = certified_controller(
            name, sol, r, st, extra=extra, nominal=nominal, premise=prem
        )
        progress.advance()
    progress.finish()
    with StageWriter(
        out, "synth", options=options, inputs=[em_file] if em_file else [], force=force
    ) as w:
        for name, c in ctrls.items():
            w.write_bytes(f"{name}/{CONTROLLER_FILE}", c.controller.to_bytes())
            w.write_text(f"{name}/{CERTIFICATE_FILE}", c.certificate.to_yaml())
        w.results["controllers"] = {n: c.status for n, c in ctrls.items()}
        w.results["timings"] = {n: c.timings for n, c in ctrls.items() if c.timings}
        w.results["error_model_sha256"] = sha
    return SynthResult(
        Path(out),
        {n: c.status for n, c in ctrls.items()},
        {n: c.certificate.model_dump() for n, c in ctrls.items()},
    )


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
    """The largest S for which the robust problem of ``options`` is feasible (its
    feasibility does not depend on the cost); see :func:`qsls.pipeline.control.sls.max_feasible_s`."""
    em, _, _ = read_model(error_model)
    opts = options.model_copy(update={"S": 0.0})
    r = resolve(opts, em)
    ms = sls.max_feasible_s(
        r.model, options.T, eps_e=r.eps_e, radius=r.radius, eps_w=r.eps_w, delta=r.delta,
        strictly_proper=options.strictly_proper, solver=options.solver,
    )  # fmt: skip
    min_xy = sls.min_phi_xy(
        r.model, options.T, strictly_proper=options.strictly_proper, solver=options.solver
    )
    if not ms.s_max >= 0:
        # at S = 0 the constraint is (eps_e ||Phi_xy|| + eps_w ||Phi_xx H|| + Delta) / r <= 1,
        # with ||Phi_xy|| >= its minimum at T and ||Phi_xx H|| >= ||H|| = 1 (Phi_xx(1) = I)
        lower = (r.eps_e * min_xy + r.eps_w + r.delta) / r.radius
        raise InfeasibleError(
            f"no S >= 0 is feasible at T = {options.T}: even S = 0 needs "
            f"(eps_e ||Phi_xy|| + eps_w ||Phi_xx H|| + Delta) / r < 1, and with eps_e = "
            f"{r.eps_e:.4g}, the smallest ||Phi_xy|| = {min_xy:.4g} at this T, eps_w = "
            f"{r.eps_w:.4g}, Delta = {r.delta:.4g} and r = {r.radius:.4g} it is at least "
            f"{lower:.4g}; lower eps_e (a percentile) or Delta, or raise r or T",
            {"T": options.T, "min_norm_phi_xy": min_xy, "lower_bound_at_S0": lower},
        )
    return MaxFeasibleSResult(
        ms.s_max, min_xy, options.T, r.eps_e, r.radius, r.eps_w, r.delta, ms.iterations
    )
