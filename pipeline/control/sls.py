"""The FIR output-feedback SLS problem (docs/synthesis.md#fir-responses-and-achievability).

Taps ``k = 0..T`` of the four closed-loop responses (paper: ``Phi_xw, Phi_uw, Phi_xe,
Phi_ue``)::

    x = Phi_xx (H w) + Phi_xy e,     u = Phi_ux (H w) + Phi_uy e

with ``x[k] = sum_t Phi_xx(t) H w[k-t] + Phi_xy(t) e[k-t]``. Achievability (paper eq.
sls_constraints), tap by tap::

    Phi_xx(1) = I,  Phi_xy(1) = B Phi_uy(0),  Phi_ux(1) = Phi_uy(0) C
    Phi_xx(k+1) = A Phi_xx(k) + B Phi_ux(k) = Phi_xx(k) A + Phi_xy(k) C     (k = 1..T)
    Phi_xy(k+1) = A Phi_xy(k) + B Phi_uy(k),  Phi_ux(k+1) = Phi_ux(k) A + Phi_uy(k) C
    with Phi(T+1) = 0 (FIR).

Eliminated (issue 27): the equations determine ``Phi_ux``, ``Phi_xy`` and ``Phi_uy`` from
``Phi_xx(2..T)`` (:mod:`qsls.pipeline.control.achievable`: each an affine map reaching back
at most three taps, built once per structure with scipy.sparse); the only variable is those
free taps (on the plant's block pattern: the three axes never couple), the only equations
are that ``Phi_xx(k+1) - A Phi_xx(k)`` lies in the range of ``B`` and the fixed zeros of
``Phi_uy``. Each response's absolute values get one epigraph, shared by every norm and cost
that reads them. Every number that a sweep varies (weights, ``S``, ``eps_e``, ``r``,
``eps_w``, ``Delta``, the imitation target) is a cvxpy Parameter: a problem structure
(``T``, norm, cost, robust, timing, premise norms) is compiled once (DPP) and then only
re-solved, cold. Measured at T = 50 (L1 robust c_QR): Clarabel 25 iterations on 2.4k
variables instead of 37 on 14k; build plus solve 5x less CPU (benchmarks/bench_synth.py).

Mirrored (issue 37, :func:`qsls.pipeline.control.achievable.mirror_maps`): where a signed
permutation maps one axis onto another and leaves the plant and every weight invariant (x and
y), the image axis's free taps are the source's with signs, with no epigraph of their own.
Only the rows something reads get an epigraph (``W_x``'s nonzero rows, not a mirror's image);
``c_QR``'s rows of lightly weighted states (:data:`LIGHT_ROW`) are checked after the solve
(:func:`light_rows_hold`). Measured in docs/performance.md (30 % less CPU from the mirror;
0.137-0.146 CPU s against 0.195-0.204 with :data:`FAST` at T = 50, the same optimum).

Norms: the induced inf-to-inf norm of an FIR operator is the largest row sum of absolute
values over all its taps side by side (:func:`l1_norm`); H2 is the Frobenius norm over all
taps (:func:`h2_norm`). The objective is the :class:`~qsls.pipeline.control.costs.Cost` the
structure holds (``c_QR``, ``c_im``, Dinkelbach's ratio, ...): it builds its own expression
from what the problem exposes (:meth:`SLSProblem.response`, :meth:`SLSProblem.sums`, the
premise's norms) and sets its own Parameters; the problem never asks which cost it is.

Robustness constraint (convex form of the paper's)::

    (S + eps_e / r) ||Phi_xy|| + (eps_w ||Phi_xx H|| + eps_b G_b + Delta) / r <= 1 - backoff

(``G_b`` with integral action only, :mod:`qsls.pipeline.control.integral`). ``backoff`` (1e-6)
keeps it strict after the solver's tolerance: a recomputed certificate still has ``lhs < 1``.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np
import scipy.sparse as sp

from qsls.pipeline.control.achievable import (
    Mirror,
    block_pattern,
    eliminate,
    find_mirrors,
    implied_zero_taps,
    mirror_maps,
)
from qsls.pipeline.control.achievable import achievability_residuals as achievability_residuals
from qsls.pipeline.control.costs import QR, Cost, PremiseNorms, cost_of, is_diagonal
from qsls.pipeline.control.costs import cost_value as cost_value  # c_QR, c_im from taps
from qsls.pipeline.control.guarantee import (
    VELOCITY,
    Norms,
    error_weights,
    measured_channels,
    outlier_channels,
    premise_bound,
    system_norms,
)
from qsls.pipeline.control.integral import bias_norm, bias_sums, integral_action
from qsls.pipeline.control.options import psd_sqrt as psd_sqrt
from qsls.pipeline.control.taps import (  # re-exported: the responses are the problem's variables
    RESPONSES,
    Taps,
)
from qsls.pipeline.control.taps import h2_norm as h2_norm
from qsls.pipeline.control.taps import l1_norm as l1_norm
from qsls.pipeline.control.taps import side_by_side as side_by_side
from qsls.pipeline.core.plant import NX, LinearModel
from qsls.pipeline.premise.numbers import PremiseNumbers

Norm = Literal["l1", "h2"]
ROBUST_BACKOFF = 1e-6
TIGHT = {"tol_feas": 1e-10, "tol_gap_abs": 1e-10, "tol_gap_rel": 1e-10}
"""Clarabel's tolerances for the attitude plant: its optimum sits on the robustness constraint
with responses ten times larger than the hover plant's, and the default 1e-8 left the
realization check (1e-8) failing by a factor of 3; these pass it by 2. Where Clarabel cannot
reach them (near the feasibility boundary) the default tolerances are used and the
certificate's checks decide as for any solution."""
FAST = {**TIGHT, "iterative_refinement_enable": False}
""":data:`TIGHT` without Clarabel's iterative refinement of each KKT solve, tried first (issue
37): at the quickstart's setting, T = 50, the same iterations at ~55 % of the time, the
objective within 3e-9 relative and the realization error 3e-10 (limit 1e-8). Where it ends
inaccurate, :data:`TIGHT` is solved, then the default tolerances."""


# --------------------------------------------------------------------------- problem
@dataclass(frozen=True)
class Structure:
    """What fixes a compiled problem: the model, the horizon, norm, cost, timing. ``cost``
    is a :class:`~qsls.pipeline.control.costs.Cost` (a config's name for one is looked up in
    :data:`~qsls.pipeline.control.costs.COSTS` here)."""

    T: int
    norm: Norm = "l1"
    cost: Cost = QR
    robust: bool = True
    strictly_proper: bool = False
    # Q and R diagonal: Parameter vectors (a full Parameter matrix doubled Clarabel's time at
    # T = 50); :func:`solve` picks this from the values.
    diagonal_weights: bool = True
    # The premise's norms (docs/guarantee.md), compiled into the problem: W_x, W_e, which
    # error channels the controller reads (position-only: Phi_uy's velocity columns are 0),
    # and the outlier count m per window (G_m enters the robustness constraint when m > 0).
    state_scale: tuple[float, ...] = (1.0,) * 6
    error_scale: tuple[float, ...] = (1.0,) * 6
    measure: str = "full"
    m: int = 0
    gate: bool = False  # robust problems: the certified velocity deviation stays within V
    # The bias term (docs/guarantee.md#the-bias-term): integral action, eps_b G_b in lhs.
    bias: bool = False
    # Responses on the plant's decoupled blocks (its axes): exact with diagonal Q, R and a
    # nominal without cross terms (achievable.py); :func:`solve` turns it off otherwise.
    decoupled: bool = True
    # Mirrored groups (x and y) solved once (achievable.mirror_maps): exact when the weights
    # are mirror-invariant and nothing is imitated; :func:`solve` turns it on where it is.
    mirrored: bool = False
    # States whose c_QR L1 rows are left out (weights below LIGHT_ROW: the attitude plant's
    # extra states), checked after the solve; :func:`solve` re-solves where one would bind.
    light_states: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "cost", cost_of(self.cost))


def mirrors_of(
    model: LinearModel, s: Structure, Q: np.ndarray | None = None, R: np.ndarray | None = None
) -> tuple[Mirror, ...]:
    """The plant's mirrored groups that leave ``s``'s premise weights (and the diagonals of
    ``Q``, ``R`` when given) invariant (:func:`qsls.pipeline.control.achievable.find_mirrors`)."""
    n = model.nx
    rows = np.arange(n)
    measured = measured_channels(s.measure)
    keys = [
        np.asarray(s.state_scale, float), np.asarray(s.error_scale, float),
        np.isin(rows, measured), np.isin(rows, outlier_channels(s.measure, s.m)),
        np.isin(rows, VELOCITY),
    ]  # fmt: skip
    ukeys = [np.zeros(model.nu)]
    if Q is not None and R is not None and len(Q) == n and len(R) == model.nu:
        keys.append(np.diag(Q))  # (weights of another size are read by no cost of the problem)
        ukeys.append(np.diag(R))
    return find_mirrors(model, np.column_stack(keys), np.column_stack(ukeys))


def _pairs(mirrors: tuple[Mirror, ...]) -> tuple[tuple[int, int], ...]:
    return tuple((m.source, m.image) for m in mirrors)


NO_PREMISE = PremiseNumbers(eps=0.0, S=0.0, radius=1.0, eps_w=0.0, delta=0.0)
"""The premise of an instance that states none: every number 0, ``r = 1``."""


@dataclass(frozen=True)
class Values:
    """The numbers of one problem instance (the cvxpy Parameters' values): the cost's
    weights, the premise's numbers (``eps`` is ``eps_e``; ``eps_o`` read by robust problems
    with ``m > 0``, ``gate`` by structures with a gate; ``R0`` and ``m`` by none), the
    nominal responses to imitate and Dinkelbach's ``lambda`` (cost ``ratio`` only)."""

    Q: np.ndarray = field(default_factory=lambda: np.diag([10.0, 10, 10, 1, 1, 1]))
    R: np.ndarray = field(default_factory=lambda: np.diag([1.0, 1, 0.1]))
    numbers: PremiseNumbers = NO_PREMISE
    nominal: Taps | None = None
    ratio_lambda: float = 0.0


@dataclass(frozen=True)
class Solution:
    """One solve: cvxpy's status mapped to ``optimal | infeasible | inaccurate | error``."""

    status: str
    solver_status: str
    taps: Taps | None
    objective: float
    build_time_s: float
    solve_time_s: float
    compiled: bool  # this call compiled the problem (first solve of the structure)


class SLSProblem:
    """One compiled FIR SLS problem; :meth:`solve` sets the Parameters and re-solves.

    The variable is ``z``, the free taps of :func:`qsls.pipeline.control.achievable.eliminate`
    (every response an affine map of it, the range equations its only equality constraints).
    Each response's absolute values get one epigraph ``t >= |M z + f|`` (rows that are
    constant are constants), shared by every norm and cost that reads them: all are
    nonnegative weighted sums of those absolute values (:meth:`_sums`)."""

    def __init__(self, model: LinearModel, structure: Structure) -> None:
        import cvxpy as cp

        t0 = time.perf_counter()
        s = structure
        if s.T < 2:
            raise ValueError(f"horizon T must be at least 2, got {s.T}")
        self.model, self.structure = model, s
        T = s.T
        self.pattern = block_pattern(model, s.decoupled)
        self.maps = mp = eliminate(model, T, self.pattern)
        # entries that copy a mirrored group's (not bounded twice; achievable.mirror_maps)
        self.dropped: dict[str, np.ndarray] = {}
        self.mirrors = mirrors_of(model, s) if s.mirrored and s.decoupled else ()
        if self.mirrors:
            self.maps, self.dropped = mp, _ = mirror_maps(mp, model, T, self.pattern, self.mirrors)
        self.z = z = cp.Variable(mp.n_free, name="free_taps")
        measured = measured_channels(s.measure)
        # Phi_uy's taps fixed at 0: tap 0 when strictly proper, the unread channels' columns
        tap, _, col = mp.Phi_uy.entry()
        unread = ~np.isin(col, measured)
        self.fixed_uy = unread | ((tap == 0) if s.strictly_proper else False)
        # the last taps of an unread column follow from the earlier ones: not imposed twice
        implied = unread & (tap > s.T - implied_zero_taps(model, self.pattern)[col])
        imposed = self.fixed_uy & ~implied & ~self.copies("Phi_uy")
        E = sp.vstack([mp.E, mp.Phi_uy.M[imposed]]).tocsr()
        e = np.concatenate([mp.e, mp.Phi_uy.f[imposed]])
        rows = np.diff(E.indptr) > 0  # a fixed tap outside the block pattern is no equation
        self.E = E[rows]
        self._cons: list[Any] = [self.E @ z + e[rows] == 0]
        self._epi: dict[str, tuple[np.ndarray, np.ndarray, Any]] = {}
        self.cost = cost = s.cost
        self._read = self._rows_read()
        # the bias term's partial sums P_K (control/integral.py), built once for both uses
        self._bias = bias_sums(mp.Phi_xx_H, model.bias_dirs) if s.bias else None
        norms = self._premise_norms() if s.robust or cost.needs_norms else None
        if self._bias is not None:  # integral action: P_T = 0
            self._cons += integral_action(self._bias, z, self._copied_rows())
        p: dict[str, Any] = {}
        if s.robust:
            assert norms is not None
            self._cons += self._robustness_constraints(p, norms)
        objective = cost.objective(self, p, norms)
        self.params = p
        self.problem = cp.Problem(
            cp.Minimize(cp.Constant(0.0) if objective is None else objective), self._cons
        )
        self.construct_time_s = time.perf_counter() - t0
        self._compiled = False

    # ---- the premise's norms and the robustness constraint
    def _premise_rows(self) -> np.ndarray:
        """The state rows the premise's norms read: ``W_x``'s nonzero rows, and the velocity
        rows under a gate (rows weighted 0 add nothing to a maximum of nonnegative terms)."""
        s, rows = self.structure, np.arange(self.model.nx)
        return (np.asarray(s.state_scale) > 0) | (s.gate & np.isin(rows, VELOCITY))

    def _copied_rows(self) -> np.ndarray:
        """The state rows of a mirrored group's image (every row sum there equals its source's:
        a maximum over rows, or a bound per row, need not read them)."""
        _, i, _ = self.maps.Phi_xy.entry()
        return np.isin(np.arange(self.model.nx), i[self.copies("Phi_xy")])

    def _rows_read(self) -> dict[str, np.ndarray]:
        """Per response, the rows some norm or cost reads through the shared epigraphs; only
        these get one (:meth:`_epigraph`)."""
        s, nx, nu = self.structure, self.model.nx, self.model.nu
        premise = self._premise_rows() if s.robust or self.cost.needs_norms else np.zeros(nx, bool)
        read = {
            "Phi_xy": premise, "Phi_xx_H": premise,
            "Phi_ux_H": np.zeros(nu, bool), "Phi_uy": np.zeros(nu, bool),
        }  # fmt: skip
        for name, rows in self.cost.epigraph_rows(self).items():
            read[name] = read[name] | rows
        return read

    def _premise_norms(self) -> PremiseNorms:
        """The premise's norms (docs/guarantee.md) on the shared epigraphs:
        ``N = max_i w_x,i sum_tj |Phi_xy(t)_ij| / w_e,j``, ``N_w = max_i w_x,i sum_tj
        |(Phi_xx(t) H)_ij|`` and ``G_m = max_i w_x,i g_i`` with ``g_i`` the sum of the ``m``
        largest over taps of ``sum_{j outlier} |Phi_xy(t)_ij|`` (``cp.sum_largest``). Keeps
        ``N``'s and ``N_w``'s row sums and the per-row ``g_i`` for the velocity gate
        (:meth:`_robustness_constraints`)."""
        import cvxpy as cp

        s, T = self.structure, self.structure.T
        wx = np.asarray(s.state_scale, float)
        inv_e = error_weights(s.error_scale, measured_channels(s.measure))
        self._rs_xh = self.sums("Phi_xx_H", lambda t, i, j: 1.0)
        self._rs_xy = self.sums("Phi_xy", lambda t, i, j: inv_e[j])
        rows = np.flatnonzero((wx > 0) & ~self._copied_rows())
        if not len(rows):  # every state weighted 0: the norms are 0
            rows = np.arange(1)
        n_xy = cp.max(cp.multiply(wx[rows], self._rs_xy[rows]))
        n_xx = cp.max(cp.multiply(wx[rows], self._rs_xh[rows]))
        channels = outlier_channels(s.measure, s.m)
        self._g_rows: dict[int, Any] = {}
        g_b, self._gb_rows = None, {}
        if self._bias is not None:  # G_b on its own epigraph, the gate's g_b,i per velocity row
            vel = np.isin(np.arange(self.model.nx), VELOCITY) & s.gate
            g_b, per_row, cons = bias_norm(self._bias, self.z, wx, rows, vel, self._copied_rows())
            self._cons += cons
            self._gb_rows = {i: per_row[i] for i in VELOCITY if i in per_row}
        if not channels:
            return PremiseNorms(n_xy, n_xx, None, g_b)
        per_tap = self.sums("Phi_xy", lambda t, i, j: np.isin(j, channels), by_tap=True)
        k = min(s.m, T)

        def g(i: int) -> Any:  # a new expression per use: the compiled problem is unchanged
            return cp.sum_largest(per_tap[i * T : (i + 1) * T], k)

        g_m = cp.max(cp.hstack([wx[i] * g(int(i)) for i in rows]))
        self._g_rows = {i: g(i) for i in VELOCITY if not self._copied_rows()[i]}
        return PremiseNorms(n_xy, n_xx, g_m, g_b)

    def _robustness_constraints(self, p: dict[str, Any], norms: PremiseNorms) -> list:
        """The robustness constraint (module docstring; docs/guarantee.md)
        ``(S + eps_e/r) N + (eps_w/r) N_w + (eps_o/r) G_m <= 1 - Delta/r - backoff`` with its
        numbers as Parameters, and with a gate ``rho_v <= V`` per velocity row
        (``guarantee.velocity_deviation``): ``eps_w |Phi_xx H|_i + (eps + S r) |Phi_xy W_e^-1|_i
        + eps_o g_i <= V``."""
        import cvxpy as cp

        s = self.structure
        p["c_xy"] = cp.Parameter(nonneg=True, name="S_plus_eps_e_over_r")
        p["c_xx"] = cp.Parameter(nonneg=True, name="eps_w_over_r")
        p["c_rhs"] = cp.Parameter(name="one_minus_delta_over_r")
        lhs = p["c_xy"] * norms.N + p["c_xx"] * norms.N_w
        if norms.G_b is not None:
            p["c_b"] = cp.Parameter(nonneg=True, name="eps_b_over_r")
            lhs = lhs + p["c_b"] * norms.G_b
        if norms.G_m is not None:
            p["c_o"] = cp.Parameter(nonneg=True, name="eps_o_over_r")
            lhs = lhs + p["c_o"] * norms.G_m
        cons = [lhs <= p["c_rhs"]]
        if s.gate:
            for name in ("g_w", "g_d", "g_o", "g_b", "g_V"):
                p[name] = cp.Parameter(nonneg=True, name="gate_" + name)
            copied = self._copied_rows()
            for i in (i for i in VELOCITY if not copied[i]):  # an image's row copies its source's
                row = p["g_w"] * self._rs_xh[i] + p["g_d"] * self._rs_xy[i]
                if i in self._g_rows:
                    row = row + p["g_o"] * self._g_rows[i]
                if norms.G_b is not None:
                    row = row + p["g_b"] * self._gb_rows[i]
                cons.append(row <= p["g_V"])
        return cons

    # ---- building blocks
    def _epigraph(self, name: str) -> list:
        """``t >= |M z + f|`` over the rows of response ``name`` that vary (fixed zeros of
        ``Phi_uy`` excluded); the constant rows' absolute values are kept as numbers."""
        import cvxpy as cp

        aff = getattr(self.maps, name)
        varies = np.diff(aff.M.indptr) > 0
        if name == "Phi_uy":
            varies &= ~self.fixed_uy
        _, i, _ = aff.entry()
        drop = self.copies(name) | ~self._read[name][i]  # copies, and rows nothing reads
        varies &= ~drop
        const = np.where(varies | drop, 0.0, np.abs(aff.f))
        if name == "Phi_uy":
            const[self.fixed_uy] = 0.0
        t = cp.Variable(int(varies.sum()), name="abs_" + name)
        ex = aff.M[varies] @ self.z + aff.f[varies]
        self._epi[name] = (varies, const, t)
        return [ex <= t, -ex <= t]

    def copies(self, name: str) -> np.ndarray:
        """The entries of response ``name`` that copy a mirrored group's (none unmirrored)."""
        aff = getattr(self.maps, name)
        return self.dropped.get(name, np.zeros(aff.M.shape[0], dtype=bool))

    def sums(self, name: str, weight: Any, *, by_tap: bool = False) -> Any:
        """``sum weight(tap, i, j) |Phi(tap)_ij|`` per row ``i`` (per row and tap, row-major,
        with ``by_tap``), from the epigraph of response ``name`` (made on first use)."""
        aff = getattr(self.maps, name)
        if name not in self._epi:
            self._cons += self._epigraph(name)
        varies, const, t = self._epi[name]
        tap, i, j = aff.entry()
        w = np.broadcast_to(np.asarray(weight(tap, i, j), float), i.shape)
        out = i * aff.taps + tap if by_tap else i
        n_out = aff.rows * aff.taps if by_tap else aff.rows
        agg = sp.csr_matrix((w, (out, np.arange(len(i)))), shape=(n_out, len(i)))
        return agg[:, varies] @ t + agg @ const

    def response(self, name: str, support: np.ndarray | None = None) -> Any:
        """Response ``name``'s entries (``M z + f``, those ``support`` marks) as a cvxpy
        expression of the free taps, in the order of its map's ``entry()``."""
        aff = getattr(self.maps, name)
        if support is None:
            return aff.M @ self.z + aff.f
        return aff.M[support] @ self.z + aff.f[support]

    def shares_mirrors(self, Q: np.ndarray, R: np.ndarray) -> bool:
        """``Q`` and ``R`` leave this problem's mirrored groups invariant."""
        return _pairs(mirrors_of(self.model, self.structure, Q, R)) == _pairs(self.mirrors)

    # ---- parameters
    def set_values(self, v: Values) -> None:
        """The Parameters of the premise's constraints, then the cost's (its own)."""
        self._set_premise(v)
        self.cost.set_values(self, self.params, v)

    def _set_premise(self, v: Values) -> None:
        s, p, n = self.structure, self.params, v.numbers
        if s.robust:
            p["c_xy"].value = float(n.slope_ratio)
            p["c_xx"].value = float(n.eps_w / n.radius)
            p["c_rhs"].value = float(1.0 - n.delta / n.radius - ROBUST_BACKOFF)
            if "c_o" in p:
                p["c_o"].value = float(n.eps_o / n.radius)
            if "c_b" in p:
                p["c_b"].value = float(n.eps_b / n.radius)
            if "g_V" in p:
                if n.gate is None:
                    raise ValueError("this problem was built with a velocity gate: give its V")
                p["g_w"].value = float(n.eps_w)
                p["g_d"].value = float(premise_bound(n.eps, n.S, n.radius))
                p["g_o"].value = float(n.eps_o)
                if "g_b" in p:  # (a problem built without the bias term has none)
                    p["g_b"].value = float(n.eps_b)
                p["g_V"].value = float(n.gate)

    def taps(self) -> Taps:
        z = np.asarray(self.z.value)
        # Phi_uy's fixed taps are structurally zero (the solver returns ~1e-14)
        zero = {"Phi_uy": self.fixed_uy}
        return Taps(**{n: getattr(self.maps, n).value(z, zero.get(n)) for n in RESPONSES})

    def solve(
        self, values: Values, *, solver: str = "CLARABEL", solver_options: dict | None = None
    ) -> Solution:
        """Set the Parameters from ``values`` and solve; never raises on solver trouble."""
        import cvxpy as cp

        self.set_values(values)
        compiled = not self._compiled
        t0 = time.perf_counter()
        try:
            # warm_start=False: cvxpy would otherwise update the previous solver object in
            # place, and the answer (these LPs have many optimal points) would depend on
            # which instance this process solved before; cold solves are reproducible.
            # (Measured, issue 27: Clarabel's in-place data update keeps its equilibration
            # from the earlier instance, so answers differ bitwise; with equilibration off it
            # is reproducible but only 4% faster than a cold solve with it, at T = 20.)
            opts = {"warm_start": False, **(solver_options or {})}
            with warnings.catch_warnings():  # the status says it; the library never prints
                warnings.simplefilter("ignore", UserWarning)
                self.problem.solve(solver=solver, **opts)
            solver_status = str(self.problem.status)
        except cp.error.SolverError as exc:
            solver_status = f"solver_error: {str(exc).splitlines()[0] if str(exc) else exc!r}"
        wall = time.perf_counter() - t0
        self._compiled = True
        # build: cvxpy's compile (applying the Parameters on a re-solve), plus building the
        # expression tree on the first call; solve: the rest of the call (the solver).
        comp = self.problem.compilation_time or 0.0
        solve_t = max(wall - comp, 0.0)
        build_t = comp + (self.construct_time_s if compiled else 0.0)
        if solver_status == cp.OPTIMAL:
            status = "optimal"
        elif solver_status in (cp.INFEASIBLE, cp.INFEASIBLE_INACCURATE):
            status = "infeasible"
        elif solver_status == cp.OPTIMAL_INACCURATE:
            status = "inaccurate"
        else:
            status = "error"
        taps = self.taps() if status in ("optimal", "inaccurate") else None
        obj = float(self.problem.value) if taps is not None else float("nan")
        return Solution(status, solver_status, taps, obj, build_t, solve_t, compiled)


# --------------------------------------------------------------------------- cache
_CACHE: dict[tuple, SLSProblem] = {}
_CACHE_MAX = 16


def _model_key(model: LinearModel) -> tuple:
    return tuple(
        np.asarray(m, dtype=float).round(15).tobytes() for m in (model.A, model.B, model.C, model.H)
    )


def get_problem(model: LinearModel, structure: Structure) -> SLSProblem:
    """The compiled problem for ``structure`` (built once per process, then re-solved)."""
    key = (_model_key(model), structure)
    prob = _CACHE.get(key)
    if prob is None:
        if len(_CACHE) >= _CACHE_MAX:
            _CACHE.pop(next(iter(_CACHE)))
        prob = _CACHE[key] = SLSProblem(model, structure)
    return prob


def _fits_blocks(model: LinearModel, nominal: Taps) -> bool:
    """Every entry of ``nominal`` outside the plant's block pattern is zero."""
    pattern = block_pattern(model, True)
    return all(not np.any(getattr(nominal, name)[:, ~pattern[name]]) for name in RESPONSES)


def solve(
    model: LinearModel,
    structure: Structure,
    values: Values,
    *,
    solver: str = "CLARABEL",
    solver_options: dict | None = None,
) -> Solution:
    """Solve one instance, re-using this process's compiled problem for the structure
    (its weights' form and block pattern chosen to suit ``values``)."""
    diag = is_diagonal(values.Q) and is_diagonal(values.R)
    decoupled = diag and (values.nominal is None or _fits_blocks(model, values.nominal))
    mirrored = (
        decoupled and values.nominal is None
        and _pairs(mirrors_of(model, structure, values.Q, values.R))
        == _pairs(mirrors_of(model, structure))
    )  # fmt: skip
    structure = replace(
        structure, diagonal_weights=diag, decoupled=decoupled, mirrored=mirrored,
        light_states=light_states(structure, values) if diag else (),
    )  # fmt: skip
    sol = _solve_structure(model, structure, values, solver, solver_options)
    if sol.taps is not None and not light_rows_hold(sol.taps, model, values, structure):
        sol = _solve_structure(
            model, replace(structure, light_states=()), values, solver, solver_options
        )
    return sol


def _solve_structure(
    model: LinearModel,
    structure: Structure,
    values: Values,
    solver: str,
    solver_options: dict | None,
) -> Solution:
    problem = get_problem(model, structure)
    if model.nx > NX and solver == "CLARABEL" and solver_options is None:
        for opts in (FAST, TIGHT):
            sol = problem.solve(values, solver=solver, solver_options=opts)
            if sol.status != "inaccurate":  # else the next, the default tolerances last
                return sol
    return problem.solve(values, solver=solver, solver_options=solver_options)


def light_states(structure: Structure, values: Values) -> tuple[int, ...]:
    """The states whose rows the structure's cost lets a problem (diagonal weights) leave out
    and check after the solve (``c_QR``'s L1: the attitude plant's extra states,
    :meth:`~qsls.pipeline.control.costs.QRCost.light_rows`)."""
    return structure.cost.light_rows(structure.norm, values.Q)


def light_rows_hold(taps: Taps, model: LinearModel, values: Values, structure: Structure) -> bool:
    """The rows left out (:func:`light_states`) do not change the optimum: the solution's full
    cost is the solved problem's (:meth:`~qsls.pipeline.control.costs.Cost.light_rows_hold`)."""
    if not structure.light_states:
        return True
    return structure.cost.light_rows_hold(taps, model, values, structure.light_states)


# --------------------------------------------------------------------------- feasibility
@dataclass(frozen=True)
class Shape:
    """The premise's norms a feasibility question is asked in (:class:`Structure`'s fields)."""

    state_scale: tuple[float, ...] = (1.0,) * 6
    error_scale: tuple[float, ...] = (1.0,) * 6
    measure: str = "full"
    m: int = 0
    gate: bool = False
    bias: bool = False

    def structure(self, T: int, cost: Cost | str, strictly_proper: bool) -> Structure:
        return Structure(
            T, "l1", cost_of(cost), False, strictly_proper, state_scale=self.state_scale,
            error_scale=self.error_scale, measure=self.measure, m=self.m, gate=self.gate,
            bias=self.bias,
        )  # fmt: skip

    def norms(self, taps: Taps, model: LinearModel) -> Norms:
        """The premise's norms of ``taps``, ``G_b`` always (without integral action too)."""
        return system_norms(
            taps.Phi_xy, taps.Phi_xx @ model.H, state_scale=self.state_scale,
            error_scale=self.error_scale, measured=measured_channels(self.measure),
            outlier_channels=outlier_channels(self.measure, self.m), m=self.m,
            bias_dirs=model.bias_dirs,
        )  # fmt: skip
