"""Why a robust problem is infeasible, and the largest feasible ``S``: the diagnosis an
infeasible ``qsls synth`` reports (the necessary condition ``(S + eps_e / r) N_lower < 1``, the smallest
achievable ``||Phi_xy||`` at ``T``, the largest feasible ``S``) and ``qsls synth
--max-feasible-s``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from qsls.pipeline.control import largest_s
from qsls.pipeline.control.guarantee import min_norm_bound, necessary_condition
from qsls.pipeline.control.options import ProblemOptions
from qsls.pipeline.control.problem import Resolved, resolve
from qsls.pipeline.core.errors import InfeasibleError
from qsls.pipeline.premise.choose import read_model
from qsls.pipeline.premise.numbers import PremiseNumbers


def diagnose(
    r: Resolved, T: int, strictly_proper: bool, solver: str = "CLARABEL"
) -> dict[str, Any]:
    """Why a robust problem is infeasible: the necessary condition, the smallest
    achievable ``N`` at ``T`` and the largest feasible ``S``."""
    nec = necessary_condition(r.numbers, r.shape.state_scale, r.shape.error_scale)
    n_lower = min_norm_bound(r.shape.state_scale, r.shape.error_scale)
    min_xy = largest_s.min_phi_xy(
        r.model, T, strictly_proper=strictly_proper, solver=solver, shape=r.shape
    )
    ms = largest_s.max_feasible_s(
        r.model, T, r.numbers, shape=r.shape, strictly_proper=strictly_proper, solver=solver
    )
    return {
        "S": r.numbers.S,
        "eps_e": r.numbers.eps,
        "radius": r.numbers.radius,
        "S_plus_eps_e_over_r": r.numbers.slope_ratio,
        "N_lower": n_lower,
        "necessary": nec,
        "necessary_condition_holds": bool(nec < 1.0),
        "min_norm_phi_xy": min_xy,
        "max_feasible_S": ms.s_max,
        "T": T,
    }


def diagnosis_message(d: dict[str, Any]) -> str:
    """One line: what fails, and what could help (a radius cannot help when ``S N_lower >= 1``)."""
    parts = []
    lower = d["N_lower"]
    cond = (
        "S + eps_e/r < 1" if lower == 1.0 else f"(S + eps_e/r) N_lower < 1 (N_lower = {lower:.4g})"
    )
    if not d["necessary_condition_holds"]:
        parts.append(
            f"S + eps_e/r = {d['S_plus_eps_e_over_r']:.4g} fails the necessary condition {cond} "
            "(N >= N_lower = max over positions of w_x / w_e for this plant)"
        )
    else:
        parts.append(f"the necessary condition {cond} holds ({d['necessary']:.4g})")
    parts.append(
        f"the smallest achievable N = ||W_x Phi_xy W_e^-1|| at T={d['T']} is {d['min_norm_phi_xy']:.4g}"
    )
    if d["S"] * lower >= 1.0:
        parts.append(
            f"no radius or horizon can help: S N_lower = {d['S'] * lower:.4g} >= 1 alone breaks "
            "S N < 1; a smaller "
            "S needs a different premise (S = lofo, an error_scale that weights the velocity "
            "errors less, beta with eps_o, or measure: position)"
        )
    if d["max_feasible_S"] >= 0:
        parts.append(
            f"the largest feasible S for this setting is {d['max_feasible_S']:.6g} (S = {d['S']:.4g} given)"
        )
    elif d["S"] * lower < 1.0:
        parts.append(
            "no S >= 0 is feasible for this setting: lower eps_e (beta, error_scale, measure: "
            "position) or Delta (training flights nearer the reference), or raise r or T"
        )
    return "robust synthesis is infeasible: " + "; ".join(parts)


# --------------------------------------------------------------------------- max S
@dataclass(frozen=True)
class MaxFeasibleSResult:
    """The largest feasible ``S`` at ``T`` under the premise ``numbers`` (its ``S`` is 0:
    the one asked for), the smallest ``||Phi_xy||`` at ``T`` and Dinkelbach's iterations."""

    s_max: float
    min_norm_phi_xy: float
    T: int
    numbers: PremiseNumbers
    iterations: int

    def summary(self) -> dict[str, Any]:
        n = self.numbers
        return {
            "largest feasible S": self.s_max,
            "T": self.T,
            "eps_e": n.eps,
            "radius": n.radius,
            "eps_w": n.eps_w,
            "delta": n.delta,
            "smallest ||Phi_xy|| at T": self.min_norm_phi_xy,
            "Dinkelbach iterations": self.iterations,
        }


def max_feasible_s(error_model: Path | None, options: ProblemOptions) -> MaxFeasibleSResult:
    """The largest S for which the robust problem of ``options`` is feasible under its premise
    (its feasibility does not depend on the cost); see :func:`qsls.pipeline.control.largest_s.max_feasible_s`."""
    opts = options.model_copy(update={"S": 0.0})
    r = resolve(opts, read_model(error_model))
    ms = largest_s.max_feasible_s(
        r.model, options.T, r.numbers, shape=r.shape, strictly_proper=options.strictly_proper,
        solver=options.solver,
    )  # fmt: skip
    min_xy = largest_s.min_phi_xy(
        r.model, options.T, strictly_proper=options.strictly_proper, solver=options.solver,
        shape=r.shape,
    )  # fmt: skip
    if not ms.s_max >= 0:
        # at S = 0 the constraint is (eps N + eps_w N_w + Delta + eps_o G_m) / r <= 1, with N
        # at least its minimum at T and N_w >= min w_x (Phi_xx(1) = I)
        lower = (
            r.numbers.eps * min_xy + r.numbers.eps_w * min(r.shape.state_scale) + r.numbers.delta
        ) / r.numbers.radius
        raise InfeasibleError(
            "none feasible: lower eps_e (beta, error_scale, measure: position) or Delta, or "
            f"raise r or T: no S >= 0 is feasible at T = {options.T}: even S = 0 needs "
            f"(eps_e N + eps_w N_w + Delta + eps_o G_m) / r < 1, at least {lower:.4g} with "
            f"eps_e = {r.numbers.eps:.4g}, the smallest N = {min_xy:.4g} at this T, eps_w = "
            f"{r.numbers.eps_w:.4g}, Delta = {r.numbers.delta:.4g} and r = {r.numbers.radius:.4g}",
            {"T": options.T, "min_norm_phi_xy": min_xy, "lower_bound_at_S0": lower},
        )
    return MaxFeasibleSResult(ms.s_max, min_xy, options.T, r.numbers, ms.iterations)
