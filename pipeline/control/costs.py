"""Controller costs as objects (docs/synthesis.md#costs).

A cost is the objective of an :class:`~qsls.pipeline.control.sls.SLSProblem`: it builds its
expression once, from the problem's building blocks (the responses' shared epigraphs and the
premise's norms ``N``, ``N_w``, ``G_m``), with every number it reads a cvxpy Parameter, and
sets those Parameters for each instance. A new cost is one class here, registered in
:data:`COSTS`, one paragraph in docs/synthesis.md and one test.

- ``qr``: ``c_QR = || diag(Q^1/2, R^1/2) [Phi_xx H  Phi_xy; Phi_ux H  Phi_uy]
  diag(eps_w I, eps_e I) ||`` (the paper's qrcost), L1 or H2;
- ``imitation``: ``c_im = || diag(Q^1/2, R^1/2) (Phi - Phi_nominal) ||`` (immitationcost);
- ``min_phi_xy``: ``N``, the smallest error gain (feasibility of a slope);
- ``ratio``: ``lambda N + (eps_w/r) N_w + (eps_o/r) G_m``, Dinkelbach's step for the largest
  feasible ``S`` (:mod:`qsls.pipeline.control.largest_s`);
- ``none``: 0 (feasibility only).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    from qsls.pipeline.control.sls import SLSProblem, Values


@dataclass(frozen=True)
class PremiseNorms:
    """The premise's norms as cvxpy expressions of one problem (None where not built)."""

    N: Any  # ||W_x Phi_xy W_e^-1||
    N_w: Any  # ||W_x Phi_xx H||
    G_m: Any  # the sparse gain (None without outlier channels)


class Cost(Protocol):
    name: str
    needs_norms: bool
    """The objective reads ``N``, ``N_w``, ``G_m`` (built even for a problem that is not robust)."""
    imitates: bool
    """The objective reads nominal responses (``Values.nominal``)."""

    def objective(self, prob: SLSProblem, p: dict[str, Any], norms: PremiseNorms | None) -> Any:
        """The objective's expression, its Parameters added to ``p``."""

    def set_values(self, prob: SLSProblem, p: dict[str, Any], v: Values) -> None:
        """The Parameters of ``p`` it added, from ``v``."""


class WeightedCost:
    """``c_QR`` and ``c_im``: a weighted norm of the four responses
    (:meth:`SLSProblem.weighted_cost`, :meth:`SLSProblem.set_weights`)."""

    name: str = ""
    needs_norms: bool = False
    imitates: bool = False
    reads_H: bool = False
    """The state-disturbance columns are ``Phi H`` (``c_QR``'s ``diag(eps_w H, eps_e I)``)."""

    def objective(self, prob: SLSProblem, p: dict[str, Any], norms: PremiseNorms | None) -> Any:
        return prob.weighted_cost(p, self)

    def set_values(self, prob: SLSProblem, p: dict[str, Any], v: Values) -> None:
        prob.set_weights(v, self)

    def scale(self, v: Values) -> dict[str, float]:
        """The factor of each response block (``xx``, ``xy``, ``ux``, ``uy``)."""
        return dict.fromkeys(("xx", "xy", "ux", "uy"), 1.0)


class QRCost(WeightedCost):
    name = "qr"
    reads_H = True

    def scale(self, v: Values) -> dict[str, float]:
        n = v.numbers
        return {"xx": n.eps_w, "xy": n.eps, "ux": n.eps_w, "uy": n.eps}


class ImitationCost(WeightedCost):
    name = "imitation"
    imitates = True


class MinErrorGain:
    name = "min_phi_xy"
    needs_norms = True
    imitates = False

    def objective(self, prob: SLSProblem, p: dict[str, Any], norms: PremiseNorms | None) -> Any:
        assert norms is not None
        return norms.N

    def set_values(self, prob: SLSProblem, p: dict[str, Any], v: Values) -> None:
        return None


class RatioCost:
    name = "ratio"
    needs_norms = True
    imitates = False

    def objective(self, prob: SLSProblem, p: dict[str, Any], norms: PremiseNorms | None) -> Any:
        import cvxpy as cp

        assert norms is not None
        p["lam"] = cp.Parameter(nonneg=True, name="lambda")
        p["c_xx_ratio"] = cp.Parameter(nonneg=True, name="eps_w_over_r_ratio")
        objective = p["lam"] * norms.N + p["c_xx_ratio"] * norms.N_w
        if norms.G_m is not None:
            p["c_o_ratio"] = cp.Parameter(nonneg=True, name="eps_o_over_r_ratio")
            objective = objective + p["c_o_ratio"] * norms.G_m
        return objective

    def set_values(self, prob: SLSProblem, p: dict[str, Any], v: Values) -> None:
        p["lam"].value = float(v.ratio_lambda)
        n = v.numbers
        p["c_xx_ratio"].value = float(n.eps_w / n.radius)
        if "c_o_ratio" in p:
            p["c_o_ratio"].value = float(n.eps_o / n.radius)


class NoCost:
    name = "none"
    needs_norms = False
    imitates = False

    def objective(self, prob: SLSProblem, p: dict[str, Any], norms: PremiseNorms | None) -> Any:
        import cvxpy as cp

        return cp.Constant(0.0)

    def set_values(self, prob: SLSProblem, p: dict[str, Any], v: Values) -> None:
        return None


COSTS: dict[str, Cost] = {
    c.name: c for c in (QRCost(), ImitationCost(), MinErrorGain(), RatioCost(), NoCost())
}
"""Every cost by name."""


def cost_of(name: str) -> Cost:
    """The registered cost ``name`` (a clear error naming the others)."""
    try:
        return COSTS[name]
    except KeyError:
        raise ValueError(f"unknown cost {name!r}; the costs are {', '.join(COSTS)}") from None
