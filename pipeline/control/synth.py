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
from typing import Any, Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from qsls.pipeline.control import sls
from qsls.pipeline.control.pdgain import PDGains
from qsls.pipeline.control.plant import (
    NU,
    NX,
    PAPER_DT_S,
    PAPER_MASS_KG,
    LinearModel,
    quadrotor_model,
)
from qsls.pipeline.core.artifacts import StageWriter, sha256_file
from qsls.pipeline.core.config import Options
from qsls.pipeline.core.errors import InfeasibleError, InputError, SolverError
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.errormodel.model import ERROR_MODEL_FILE, ErrorModel, load_error_model

Number = float | str


def _matrix(value: Any, n: int, what: str, pd: bool) -> list[list[float]]:
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
    if pd:
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
    R0: Number | None = Field(None, description="R0 for gamma_strict; default: the model's R0")
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
    """Numbers for every setting; error-model names (``max``, ``p95``...) looked up."""
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
    if opts.R0 is None:
        R0 = float(em.R0) if em is not None else eps_e
    else:
        R0 = _number(opts.R0, em, "R0", "resolve_eps_e")
    H = None if opts.H is None else np.asarray(opts.H)
    model = quadrotor_model(dt=opts.dt, mass=opts.mass, H=H)
    return Resolved(
        model, np.asarray(opts.Q), np.asarray(opts.R), S, eps_e, radius, delta, R0, opts.eps_w
    )


def read_model(path: Path | None) -> tuple[ErrorModel | None, str | None, Path | None]:
    """``(error model, sha256 of error_model.yaml, file)``; all None without a path."""
    if path is None:
        return None, None, None
    em = load_error_model(path)
    p = Path(path)
    f = p / ERROR_MODEL_FILE if p.is_dir() else p
    return em, sha256_file(f), f


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
class Controller:
    """One synthesized (or reference) controller: taps, certificate and npz arrays."""

    name: str
    status: str
    taps: sls.Taps
    certificate: dict[str, Any]
    arrays: dict[str, np.ndarray]


def model_arrays(m: LinearModel) -> dict[str, np.ndarray]:
    return {"A": m.A, "B": m.B, "C": m.C, "H": m.H, "dt": np.array(m.dt), "mass": np.array(m.mass)}


def solve_one(
    r: Resolved,
    structure: sls.Structure,
    *,
    nominal: sls.Taps | None = None,
    solver: str = "CLARABEL",
) -> sls.Solution:
    """Solve one controller's problem; infeasible/failed are returned, not raised."""
    return sls.solve(r.model, structure, r.values(nominal), solver=solver)


def certified_controller(
    name: str,
    sol: sls.Solution,
    r: Resolved,
    structure: sls.Structure,
    *,
    extra: dict[str, Any] | None = None,
) -> Controller:
    """Certify a solution and assemble its certificate and arrays."""
    from qsls.pipeline.control.certify import certify
    from qsls.pipeline.control.realize import filter_bank

    assert sol.taps is not None
    status, fields = certify(sol.taps, r.model, r.setting(), solver_status=sol.status)
    q_half, r_half = sls.psd_sqrt(r.Q), sls.psd_sqrt(r.R)
    nominal = (extra or {}).get("_nominal_taps")
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
        "build_time_s": sol.build_time_s,
        "solve_time_s": sol.solve_time_s,
        "solver_status": sol.solver_status,
        "dt": r.model.dt,
        "mass": r.model.mass,
        "Q": r.Q,
        "R": r.R,
    }
    cert.update({k: v for k, v in (extra or {}).items() if not k.startswith("_")})
    bank = filter_bank(sol.taps)
    arrays = {
        **sol.taps.arrays(),
        **model_arrays(r.model),
        **bank.arrays(),
        "kind": np.array("filter_bank"),
    }
    return Controller(name, status, sol.taps, cert, arrays)


def pd_controller(r: Resolved, gains: PDGains, T: int, extra: dict[str, Any]) -> Controller:
    from qsls.pipeline.control.certify import certify
    from qsls.pipeline.control.nominal import pd_responses, spectral_radius

    K, taps = pd_responses(r.model, gains, T)
    status, fields = certify(taps, r.model, r.setting(), reference=True)
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
    arrays = {**taps.arrays(), **model_arrays(r.model), "K": K, "kind": np.array("static_gain")}
    return Controller("pd", status, taps, cert, arrays)


def nominal_from_folder(path: Path, T: int) -> sls.Taps:
    from qsls.pipeline.control.realize import CONTROLLER_FILE, taps_from_npz

    f = Path(path) / CONTROLLER_FILE
    if not f.is_file():
        raise InputError(
            f"imitate: {path} has no {CONTROLLER_FILE}; give pd, l1_nominal or a controller folder"
        )
    with np.load(f, allow_pickle=False) as data:
        return taps_from_npz(data).truncated(T)


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
        return out


def controller_plan(opts: SynthOptions) -> list[tuple[str, sls.Structure]]:
    """``(name, structure)`` of every synthesized controller, in solve order."""
    T, sp_ = opts.T, opts.strictly_proper
    if opts.controllers == "single":
        rob = "robust" if opts.robust else "nominal"
        name = f"{opts.norm}_{rob}" + ("_imitation" if opts.cost == "imitation" else "")
        return [(name, sls.Structure(T, opts.norm, opts.cost, opts.robust, sp_))]
    norms = ["l1", "h2"] if opts.norm == "both" else [opts.norm]
    plan = []
    for n in norms:
        plan += [
            (f"{n}_nominal", sls.Structure(T, n, "qr", False, sp_)),
            (f"{n}_robust", sls.Structure(T, n, "qr", True, sp_)),
            (f"{n}_robust_imitation", sls.Structure(T, n, "imitation", True, sp_)),
        ]
    return plan


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

    check_output(out, force)
    em, sha, em_file = read_model(error_model)
    r = resolve(options, em)
    plan = controller_plan(options)
    base_extra = {
        "error_model": em_file.as_posix() if em_file else None,
        "error_model_sha256": sha,
        "solver": options.solver,
    }
    if any(s.robust for _, s in plan) and r.S + r.eps_e / r.radius >= 1.0:
        d = diagnose(r, options.T, options.strictly_proper, options.solver)
        raise InfeasibleError(diagnosis_message(d), d)
    progress.start("synth", total=len(plan) + 1)
    ctrls: dict[str, Controller] = {}
    pd = pd_controller(r, options.pd, options.T, base_extra)
    ctrls["pd"] = pd
    progress.advance()
    for name, st in plan:
        nominal = None
        extra = dict(base_extra)
        if st.cost == "imitation":
            target = options.imitate
            if target == "pd":
                nominal = pd.taps
            elif target in ctrls:
                nominal = ctrls[target].taps.truncated(options.T)
            elif target in ("l1_nominal", "h2_nominal"):
                raise InputError(f"imitate: {target} is not synthesized by this configuration")
            else:
                nominal = nominal_from_folder(Path(target), options.T)
            extra["imitate"] = target
            extra["_nominal_taps"] = nominal
        sol = solve_one(r, st, nominal=nominal, solver=options.solver)
        if sol.status == "infeasible":
            d = diagnose(r, options.T, options.strictly_proper, options.solver)
            d["controller"] = name
            raise InfeasibleError(f"{name}: " + diagnosis_message(d), d)
        if sol.status == "error" or sol.taps is None:
            raise SolverError(
                f"{name}: the solver failed ({sol.solver_status}); nothing was certified"
            )
        ctrls[name] = certified_controller(name, sol, r, st, extra=extra)
        progress.advance()
    progress.finish()
    with StageWriter(
        out, "synth", options=options, inputs=[em_file] if em_file else [], force=force
    ) as w:
        for name, c in ctrls.items():
            w.write_npz(f"{name}/controller.npz", c.arrays)
            w.write_yaml(f"{name}/certificate.yaml", c.certificate)
        w.results["controllers"] = {n: c.status for n, c in ctrls.items()}
        w.results["error_model_sha256"] = sha
    return SynthResult(
        Path(out),
        {n: c.status for n, c in ctrls.items()},
        {n: c.certificate for n, c in ctrls.items()},
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
    return MaxFeasibleSResult(
        ms.s_max, min_xy, options.T, r.eps_e, r.radius, r.eps_w, r.delta, ms.iterations
    )
