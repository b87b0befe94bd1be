"""Controller costs as objects (docs/synthesis.md#costs).

A cost is the objective of an SLS problem (:class:`qsls.pipeline.control.sls.SLSProblem`),
and it owns its math: it builds its cvxpy expression once from what the problem exposes
(:class:`Problem`: the responses as affine expressions of the free taps, the shared
epigraphs' row sums, the premise's norms ``N``, ``N_w``, ``G_m``), with every number it reads
a cvxpy Parameter, sets those Parameters for each instance (:class:`Instance`), and computes
its value from stored taps. The problem takes whatever cost its :class:`Structure
<qsls.pipeline.control.sls.Structure>` holds and never asks which one it is; costs add up
(``a + b``) and scale by a number of the instance (``factor * cost``). A new cost is one
class, one paragraph in docs/synthesis.md and one test; a config names it through
:data:`COSTS`, the only place where costs have names.

- ``qr``, :data:`QR`: ``c_QR = || diag(Q^1/2, R^1/2) [Phi_xx H  Phi_xy; Phi_ux H  Phi_uy]
  diag(eps_w I, eps_e I) ||`` (the paper's qrcost), L1 or H2;
- ``imitation``, :data:`IMITATION`: ``c_im = || diag(Q^1/2, R^1/2) (Phi - Phi_nominal) ||``
  (immitationcost);
- ``min_phi_xy``: ``N``, the smallest error gain (feasibility of a slope);
- ``ratio``: ``lambda N + (eps_w/r) N_w + (eps_o/r) G_m``, Dinkelbach's step for the largest
  feasible ``S`` (:mod:`qsls.pipeline.control.largest_s`);
- ``none``: 0 (feasibility only).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

import numpy as np
import scipy.sparse as sp

from qsls.pipeline.control.achievable import Affine, Maps
from qsls.pipeline.control.options import psd_sqrt
from qsls.pipeline.control.taps import Taps, h2_norm, l1_norm, side_by_side
from qsls.pipeline.core.plant import LinearModel
from qsls.pipeline.premise.numbers import PremiseNumbers

LIGHT_ROW = 1e-4
"""A state's row of ``c_QR``'s L1 weighted below this fraction of the largest state weight is
left out of the problem and checked after the solve (:meth:`QRCost.light_rows`)."""


# --------------------------------------------------------------------------- what a cost reads
class Instance(Protocol):
    """The numbers of one problem instance (:class:`qsls.pipeline.control.sls.Values`)."""

    @property
    def Q(self) -> np.ndarray: ...
    @property
    def R(self) -> np.ndarray: ...
    @property
    def numbers(self) -> PremiseNumbers: ...
    @property
    def nominal(self) -> Taps | None: ...
    @property
    def ratio_lambda(self) -> float: ...


class Layout(Protocol):
    """What a cost reads of a problem's structure (:class:`qsls.pipeline.control.sls.Structure`)."""

    @property
    def T(self) -> int: ...
    @property
    def norm(self) -> str: ...
    @property
    def diagonal_weights(self) -> bool: ...
    @property
    def light_states(self) -> tuple[int, ...]: ...


class Problem(Protocol):
    """What a compiled problem exposes to its cost
    (:class:`qsls.pipeline.control.sls.SLSProblem`)."""

    @property
    def structure(self) -> Layout: ...
    @property
    def model(self) -> LinearModel: ...
    @property
    def maps(self) -> Maps: ...
    @property
    def pattern(self) -> dict[str, np.ndarray]: ...
    @property
    def mirrors(self) -> tuple[Any, ...]: ...

    def response(self, name: str, support: np.ndarray | None = None) -> Any:
        """Response ``name``'s entries (those ``support`` marks), affine in the free taps."""

    def sums(self, name: str, weight: Any, *, by_tap: bool = False) -> Any:
        """``sum weight(tap, i, j) |Phi(tap)_ij|`` per row, from the shared epigraph."""

    def copies(self, name: str) -> np.ndarray:
        """The entries of response ``name`` that copy a mirrored group's."""

    def shares_mirrors(self, Q: np.ndarray, R: np.ndarray) -> bool:
        """``Q`` and ``R`` leave the problem's mirrored groups invariant."""


@dataclass(frozen=True)
class PremiseNorms:
    """The premise's norms as cvxpy expressions of one problem (None where not built)."""

    N: Any  # ||W_x Phi_xy W_e^-1||
    N_w: Any  # ||W_x Phi_xx H||
    G_m: Any  # the sparse gain (None without outlier channels)
    G_b: Any = None  # the bias gain (None without the bias term)


def is_diagonal(m: np.ndarray) -> bool:
    m = np.asarray(m)
    return bool(np.array_equal(m, np.diag(np.diag(m))))


# --------------------------------------------------------------------------- costs
@dataclass(frozen=True)
class Cost:
    """A cost: :meth:`objective` builds its expression once per compiled problem (its
    Parameters added to ``p``), :meth:`set_values` sets them per instance. Immutable and
    compared by value (a :class:`~qsls.pipeline.control.sls.Structure` holding it is the key of
    a compiled problem). ``a + b`` is their sum, ``factor * cost`` a cost scaled by a number of
    the instance (:class:`Factor`)."""

    @property
    def needs_norms(self) -> bool:
        """The objective reads ``N``, ``N_w``, ``G_m`` (built even for a problem that is not
        robust)."""
        return False

    @property
    def imitates(self) -> bool:
        """The objective reads nominal responses (``Instance.nominal``)."""
        return False

    def epigraph_rows(self, prob: Problem) -> dict[str, np.ndarray]:
        """The rows of the shared epigraphs (response name -> a mask over its rows) that the
        objective reads through :meth:`Problem.sums`, beyond the premise's norms'."""
        return {}

    def objective(self, prob: Problem, p: dict[str, Any], norms: PremiseNorms | None) -> Any:
        """The objective's expression (None: no term), its Parameters added to ``p``."""
        raise NotImplementedError

    def set_values(self, prob: Problem, p: dict[str, Any], v: Instance) -> None:
        """The Parameters of ``p`` it added, from ``v``."""
        return None

    def value(self, taps: Taps, model: LinearModel, v: Instance, norm: str) -> float:
        """The cost of ``taps`` recomputed from them (NaN: not stated by this cost)."""
        return math.nan

    def light_rows(self, norm: str, Q: np.ndarray) -> tuple[int, ...]:
        """States whose rows the problem may leave out and check after the solve
        (:meth:`light_rows_hold`)."""
        return ()

    def light_rows_hold(
        self, taps: Taps, model: LinearModel, v: Instance, light: tuple[int, ...]
    ) -> bool:
        """The rows left out (``light``) do not change the optimum found without them."""
        return True

    def __add__(self, other: Cost) -> Cost:
        return Sum((*_terms(self), *_terms(other)))


def _terms(c: Cost) -> tuple[Cost, ...]:
    return c.terms if isinstance(c, Sum) else (c,)


@dataclass(frozen=True)
class Sum(Cost):
    """The sum of its terms (a term without an expression, such as ``G_m`` without outlier
    channels, adds nothing)."""

    terms: tuple[Cost, ...]

    @property
    def needs_norms(self) -> bool:
        return any(t.needs_norms for t in self.terms)

    @property
    def imitates(self) -> bool:
        return any(t.imitates for t in self.terms)

    def epigraph_rows(self, prob: Problem) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {}
        for t in self.terms:
            for name, rows in t.epigraph_rows(prob).items():
                out[name] = out[name] | rows if name in out else rows
        return out

    def objective(self, prob: Problem, p: dict[str, Any], norms: PremiseNorms | None) -> Any:
        total = None
        for t in self.terms:
            e = t.objective(prob, p, norms)
            if e is not None:
                total = e if total is None else total + e
        return total

    def set_values(self, prob: Problem, p: dict[str, Any], v: Instance) -> None:
        for t in self.terms:
            t.set_values(prob, p, v)


@dataclass(frozen=True)
class Factor:
    """A nonnegative number of the instance that scales a cost: a Parameter named ``label``,
    kept in the problem's Parameters under ``key``."""

    key: str
    label: str
    of: Callable[[Instance], float]

    def __mul__(self, cost: Cost) -> Scaled:
        return Scaled(self, cost)


@dataclass(frozen=True)
class Scaled(Cost):
    """``factor * term``."""

    factor: Factor
    term: Cost

    @property
    def needs_norms(self) -> bool:
        return self.term.needs_norms

    @property
    def imitates(self) -> bool:
        return self.term.imitates

    def epigraph_rows(self, prob: Problem) -> dict[str, np.ndarray]:
        return self.term.epigraph_rows(prob)

    def objective(self, prob: Problem, p: dict[str, Any], norms: PremiseNorms | None) -> Any:
        import cvxpy as cp

        term = self.term.objective(prob, p, norms)
        if term is None:
            return None
        p[self.factor.key] = cp.Parameter(nonneg=True, name=self.factor.label)
        return p[self.factor.key] * term

    def set_values(self, prob: Problem, p: dict[str, Any], v: Instance) -> None:
        self.term.set_values(prob, p, v)
        if self.factor.key in p:
            p[self.factor.key].value = self.factor.of(v)


@dataclass(frozen=True)
class _PremiseGain(Cost):
    """One of the premise's gains (:class:`PremiseNorms`), named by ``gain``."""

    gain: ClassVar[str]

    @property
    def needs_norms(self) -> bool:
        return True

    def objective(self, prob: Problem, p: dict[str, Any], norms: PremiseNorms | None) -> Any:
        assert norms is not None
        return getattr(norms, self.gain)


@dataclass(frozen=True)
class ErrorGain(_PremiseGain):
    """``N = ||W_x Phi_xy W_e^-1||``, the premise's error gain."""

    gain: ClassVar[str] = "N"


@dataclass(frozen=True)
class DisturbanceGain(_PremiseGain):
    """``N_w = ||W_x Phi_xx H||``, the premise's disturbance gain."""

    gain: ClassVar[str] = "N_w"


@dataclass(frozen=True)
class BiasGain(_PremiseGain):
    """``G_b``, the peak response to a constant bias (no term without the bias term,
    docs/guarantee.md#the-bias-term)."""

    gain: ClassVar[str] = "G_b"


@dataclass(frozen=True)
class SparseGain(_PremiseGain):
    """``G_m``, the premise's sparse gain (no term without outlier channels)."""

    gain: ClassVar[str] = "G_m"


@dataclass(frozen=True)
class NoCost(Cost):
    """0: feasibility only."""

    def objective(self, prob: Problem, p: dict[str, Any], norms: PremiseNorms | None) -> Any:
        import cvxpy as cp

        return cp.Constant(0.0)


# --------------------------------------------------------------------------- weighted norms
BLOCKS = {"xx": "Phi_xx", "xy": "Phi_xy", "ux": "Phi_ux", "uy": "Phi_uy"}
"""The four responses by their block of the weighted operator."""


def cost_blocks(
    taps: Taps,
    model: LinearModel,
    q_half: np.ndarray,
    r_half: np.ndarray,
    eps_w: float,
    eps_e: float,
    nominal: Taps | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The weighted operator of the cost, as ``(state rows, input rows)`` tap arrays
    ``(T+1, rows, nx + ny)``: ``c_QR``'s when ``nominal`` is None, else ``c_im``'s."""
    if nominal is None:
        xx, xy = taps.Phi_xx @ model.H * eps_w, taps.Phi_xy * eps_e
        ux, uy = taps.Phi_ux @ model.H * eps_w, taps.Phi_uy * eps_e
    else:
        n = nominal.truncated(taps.T)
        xx, xy = taps.Phi_xx - n.Phi_xx, taps.Phi_xy - n.Phi_xy
        ux, uy = taps.Phi_ux - n.Phi_ux, taps.Phi_uy - n.Phi_uy
    top = q_half @ np.concatenate([xx, xy], axis=2)
    bottom = r_half @ np.concatenate([ux, uy], axis=2)
    return top, bottom


def cost_value(
    norm: str,
    taps: Taps,
    model: LinearModel,
    q_half: np.ndarray,
    r_half: np.ndarray,
    eps_w: float,
    eps_e: float,
    nominal: Taps | None = None,
) -> float:
    """``c_QR`` or ``c_im`` in the L1 (induced inf-to-inf) or H2 norm, from taps."""
    top, bottom = cost_blocks(taps, model, q_half, r_half, eps_w, eps_e, nominal)
    full = np.concatenate([top, bottom], axis=1)
    return l1_norm(full) if norm == "l1" else h2_norm(full)


@dataclass(frozen=True)
class WeightedCost(Cost):
    """A weighted norm of the four responses, L1 or H2 as the structure's ``norm``: ``c_QR``
    and ``c_im``. The weights are Parameters: per-entry vectors when ``Q`` and ``R`` are
    diagonal (``c_QR``'s L1 then reads the shared epigraphs' row sums), full matrices
    otherwise."""

    @property
    def reads_H(self) -> bool:
        """The state-disturbance columns are ``Phi H`` (``c_QR``'s ``diag(eps_w H, eps_e I)``)."""
        return False

    def scale(self, v: Instance) -> dict[str, float]:
        """The factor of each response block (``xx``, ``xy``, ``ux``, ``uy``)."""
        return dict.fromkeys(BLOCKS, 1.0)

    def value(self, taps: Taps, model: LinearModel, v: Instance, norm: str) -> float:
        n = v.numbers
        return cost_value(
            norm, taps, model, psd_sqrt(v.Q), psd_sqrt(v.R), n.eps_w, n.eps,
            v.nominal if self.imitates else None,
        )  # fmt: skip

    def _shared_rows(self, prob: Problem) -> bool:
        """``c_QR``'s L1 with diagonal weights reads the shared epigraphs' row sums."""
        s = prob.structure
        return self.reads_H and not self.imitates and s.norm == "l1" and s.diagonal_weights

    def epigraph_rows(self, prob: Problem) -> dict[str, np.ndarray]:
        if not self._shared_rows(prob):
            return {}
        nx, nu = prob.model.nx, prob.model.nu
        cost_x = ~np.isin(np.arange(nx), prob.structure.light_states)
        return {
            "Phi_xy": cost_x, "Phi_xx_H": cost_x,
            "Phi_ux_H": np.full(nu, True), "Phi_uy": np.full(nu, True),
        }  # fmt: skip

    def _names(self) -> dict[str, str]:
        return {**BLOCKS, "xx": "Phi_xx_H", "ux": "Phi_ux_H"} if self.reads_H else dict(BLOCKS)

    def _support(self, prob: Problem, name: str) -> np.ndarray:
        """The entries of ``name`` a diagonal weight reads (kept in the Parameters' dict as
        ``support_<block>`` for :meth:`set_values`): the block pattern's, and in L1 not a
        mirror's copies (a copy adds nothing to a row's maximum, but to H2's sum)."""
        aff: Affine = getattr(prob.maps, name)
        _, i, j = aff.entry()
        support = prob.pattern[name.removesuffix("_H")][i, j]
        if prob.structure.norm == "l1":
            support = support & ~prob.copies(name)
        return support

    def objective(self, prob: Problem, p: dict[str, Any], norms: PremiseNorms | None) -> Any:
        import cvxpy as cp

        s, mp = prob.structure, prob.maps
        names = self._names()
        if self._shared_rows(prob):
            rows = []
            for block in ("x", "u"):
                n = prob.model.nx if block == "x" else prob.model.nu
                for part in ("x", "y"):
                    key = block + part
                    p["L" + key] = cp.Parameter(n, nonneg=True, name="L" + key)
                    rows.append(
                        cp.multiply(p["L" + key], prob.sums(names[key], lambda t, i, j: 1.0))
                    )
            kept = ~np.isin(np.arange(prob.model.nx), s.light_states)
            return cp.max(cp.hstack([(rows[0] + rows[1])[np.flatnonzero(kept)], rows[2] + rows[3]]))
        blocks = {}
        for key, name in names.items():
            aff: Affine = getattr(mp, name)
            if s.diagonal_weights:
                support = p["support_" + key] = self._support(prob, name)
                p["L" + key] = cp.Parameter(int(support.sum()), nonneg=True, name="L" + key)
                expr = cp.multiply(p["L" + key], prob.response(name, support))
                if self.imitates:
                    p["N" + key] = cp.Parameter(int(support.sum()), name="N" + key)
                    expr = expr - p["N" + key]
            else:
                mat = cp.reshape(prob.response(name), (aff.rows, aff.taps * aff.cols), order="F")
                p["L" + key] = cp.Parameter((aff.rows, aff.rows), name="L" + key)
                expr = p["L" + key] @ mat
                if self.imitates:
                    p["N" + key] = cp.Parameter(mat.shape, name="N" + key)
                    expr = expr - p["N" + key]
            blocks[key] = expr
        if s.norm == "h2":
            return sum(cp.sum_squares(v) for v in blocks.values())
        sums: dict[str, Any] = {}
        for key, expr in blocks.items():
            if s.diagonal_weights:
                aff = getattr(mp, names[key])
                _, i, _ = aff.entry()
                i = i[p["support_" + key]]
                agg = sp.csr_matrix(
                    (np.ones(len(i)), (i, np.arange(len(i)))), shape=(aff.rows, len(i))
                )
                sums[key] = agg @ cp.abs(expr)
            else:
                sums[key] = cp.sum(cp.abs(expr), axis=1)
        return cp.max(cp.hstack([sums["xx"] + sums["xy"], sums["ux"] + sums["uy"]]))

    def set_values(self, prob: Problem, p: dict[str, Any], v: Instance) -> None:
        s, mp = prob.structure, prob.maps
        if s.diagonal_weights and not (is_diagonal(v.Q) and is_diagonal(v.R)):
            raise ValueError("this problem was built for diagonal Q and R")
        if prob.mirrors and (self.imitates or not prob.shares_mirrors(v.Q, v.R)):
            raise ValueError("this problem was built for weights its mirrored axes share")
        qh, rh = psd_sqrt(v.Q, "Q"), psd_sqrt(v.R, "R")
        scale = self.scale(v)
        if self.imitates:
            if v.nominal is None:
                raise ValueError("the imitation cost needs nominal responses")
            nom = v.nominal.truncated(s.T)
        for key, name in BLOCKS.items():
            half = qh if key[0] == "x" else rh
            aff: Affine = getattr(mp, name)
            if s.diagonal_weights:
                w = scale[key] * np.diag(half)
                if self._shared_rows(prob):
                    p["L" + key].value = w  # per row of the shared epigraph's sums
                    continue
                tap, i, j = aff.entry()
                sup = p["support_" + key]
                p["L" + key].value = w[i[sup]]
                if self.imitates:
                    taps = getattr(nom, name)[aff.first : aff.first + aff.taps]
                    vals = taps[tap, i, j]
                    if np.any(vals[~sup] != 0):
                        raise ValueError(
                            "the nominal responses couple what this problem's block pattern keeps apart"
                        )
                    p["N" + key].value = w[i[sup]] * vals[sup]
            else:
                p["L" + key].value = scale[key] * half
                if self.imitates:
                    taps = getattr(nom, name)[aff.first : aff.first + aff.taps]
                    p["N" + key].value = half @ side_by_side(taps)


@dataclass(frozen=True)
class QRCost(WeightedCost):
    """``c_QR`` (paper eq. qrcost)."""

    @property
    def reads_H(self) -> bool:
        return True

    def scale(self, v: Instance) -> dict[str, float]:
        n = v.numbers
        return {"xx": n.eps_w, "xy": n.eps, "ux": n.eps_w, "uy": n.eps}

    def light_rows(self, norm: str, Q: np.ndarray) -> tuple[int, ...]:
        """In L1 (diagonal weights), the states whose ``Q`` is below :data:`LIGHT_ROW` of its
        largest diagonal entry (the attitude plant's extra states)."""
        if norm != "l1":
            return ()
        q = np.diag(Q)
        return tuple(int(i) for i in np.flatnonzero(q < LIGHT_ROW * q.max()))

    def light_rows_hold(
        self, taps: Taps, model: LinearModel, v: Instance, light: tuple[int, ...]
    ) -> bool:
        """The left-out rows lie below the rows kept, so the solution's full cost is the solved
        problem's optimum: ``c_QR = max_i rowsum_i``, and a problem with fewer rows has an
        optimum no larger, attained here by a feasible point."""
        rows_out = np.asarray(light, int)
        if not len(rows_out):
            return True
        qh, rh = psd_sqrt(v.Q, "Q"), psd_sqrt(v.R, "R")
        top, bottom = cost_blocks(taps, model, qh, rh, v.numbers.eps_w, v.numbers.eps)
        rows = np.abs(top).sum(axis=(0, 2))
        kept = np.delete(rows, rows_out)
        return bool(rows[rows_out].max() <= max(kept.max(), np.abs(bottom).sum(axis=(0, 2)).max()))


@dataclass(frozen=True)
class ImitationCost(WeightedCost):
    """``c_im`` (paper eq. immitationcost)."""

    @property
    def imitates(self) -> bool:
        return True


# --------------------------------------------------------------------------- the registry
def _lambda(v: Instance) -> float:
    return float(v.ratio_lambda)


def _eps_w_over_r(v: Instance) -> float:
    return float(v.numbers.eps_w / v.numbers.radius)


def _eps_o_over_r(v: Instance) -> float:
    return float(v.numbers.eps_o / v.numbers.radius)


def _eps_b_over_r(v: Instance) -> float:
    return float(v.numbers.eps_b / v.numbers.radius)


LAMBDA = Factor("lam", "lambda", _lambda)
"""Dinkelbach's ``lambda`` (``Instance.ratio_lambda``)."""
EPS_W_OVER_R = Factor("c_xx_ratio", "eps_w_over_r_ratio", _eps_w_over_r)
EPS_O_OVER_R = Factor("c_o_ratio", "eps_o_over_r_ratio", _eps_o_over_r)
EPS_B_OVER_R = Factor("c_b_ratio", "eps_b_over_r_ratio", _eps_b_over_r)

QR: Cost = QRCost()
IMITATION: Cost = ImitationCost()
MIN_ERROR_GAIN: Cost = ErrorGain()
RATIO: Cost = (
    LAMBDA * ErrorGain() + EPS_W_OVER_R * DisturbanceGain() + EPS_B_OVER_R * BiasGain()
    + EPS_O_OVER_R * SparseGain()
)  # fmt: skip
"""Dinkelbach's step: ``lambda N + (eps_w/r) N_w + (eps_b/r) G_b + (eps_o/r) G_m``."""
NONE: Cost = NoCost()

COSTS: dict[str, Cost] = {
    "qr": QR, "imitation": IMITATION, "min_phi_xy": MIN_ERROR_GAIN, "ratio": RATIO, "none": NONE,
}  # fmt: skip
"""Every cost a config or a certificate names, by that name: the one place where costs have
names (configs keep their strings; this turns them into costs, and costs back into the names a
certificate records, :func:`name_of`)."""


def cost_of(cost: str | Cost) -> Cost:
    """The cost registered as ``cost`` (a cost is itself; a clear error naming the others)."""
    if isinstance(cost, Cost):
        return cost
    try:
        return COSTS[cost]
    except KeyError:
        raise ValueError(f"unknown cost {cost!r}; the costs are {', '.join(COSTS)}") from None


def name_of(cost: Cost) -> str:
    """The name ``cost`` is registered under (an unregistered cost: its class's name)."""
    return next((k for k, c in COSTS.items() if c == cost), type(cost).__name__)
