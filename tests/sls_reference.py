"""The vectorized SLS formulation that preceded the eliminated one (issue 27), kept as the
reference the eliminated formulation is tested and benchmarked against.

Every response is a cvxpy variable (taps side by side) and every achievability equation a
constraint (``Phi_xy``'s left equations dropped as redundant since ``C = I``); the norms
take ``cp.abs`` of each response separately. Same Parameters, same :class:`Values`, same
solve path (:meth:`qsls.pipeline.control.sls.SLSProblem.solve`).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import scipy.sparse as sp

from qsls.pipeline.control.costs import (
    RATIO,
    ErrorGain,
    NoCost,
    PremiseNorms,
    WeightedCost,
)
from qsls.pipeline.control.guarantee import (
    VELOCITY,
    error_weights,
    measured_channels,
    outlier_channels,
)
from qsls.pipeline.control.sls import (
    SLSProblem,
    Structure,
    Values,
    is_diagonal,
    psd_sqrt,
)
from qsls.pipeline.control.taps import Taps, side_by_side
from qsls.pipeline.core.plant import LinearModel


def from_side_by_side(mat: np.ndarray, cols: int) -> np.ndarray:
    """Inverse of :func:`qsls.pipeline.control.taps.side_by_side`."""
    r = mat.shape[0]
    return np.transpose(mat.reshape(r, -1, cols), (1, 0, 2))


class VectorizedProblem(SLSProblem):
    """The present-until-issue-27 formulation of one structure (see the module docstring)."""

    def __init__(self, model: LinearModel, structure: Structure) -> None:
        import cvxpy as cp

        t0 = time.perf_counter()
        s = structure
        if s.T < 2:
            raise ValueError(f"horizon T must be at least 2, got {s.T}")
        self.model, self.structure = model, s
        self.cost = cost = s.cost
        # With C = I the Phi_xy equations follow from the others: Phi_xy(k) = Phi_xx(k+1) -
        # Phi_xx(k) A and Phi_uy(k) = Phi_ux(k+1) - Phi_ux(k) A (right equations), and then
        # A Phi_xy(k) + B Phi_uy(k) = [A Phi_xx(k+1) + B Phi_ux(k+1)] - [A Phi_xx(k) + B
        # Phi_ux(k)] A = Phi_xx(k+2) - Phi_xx(k+1) A = Phi_xy(k+1) (left equation). Left
        # in, these redundant rows stall the interior-point method's primal residual near
        # its tolerance; the certificate still checks every equation.
        self.drops_redundant = model.C.shape == model.A.shape and np.array_equal(
            model.C, np.eye(model.nx)
        )
        a, b, c, h = model.A, model.B, model.C, model.H
        nx, nu, ny, T = model.nx, model.nu, model.ny, s.T
        self.X = cp.Variable((nx, T * nx), name="Phi_xx")  # taps 1..T
        self.U = cp.Variable((nu, T * nx), name="Phi_ux")  # taps 1..T
        self.Y = cp.Variable((nx, T * ny), name="Phi_xy")  # taps 1..T
        self.W = cp.Variable((nu, (T + 1) * ny), name="Phi_uy")  # taps 0..T
        X, U, Y, W = self.X, self.U, self.Y, self.W
        zx = sp.kron(sp.eye(T, k=-1), sp.eye(nx), format="csc")  # (M Z) tap k = M tap k+1
        zy = sp.kron(sp.eye(T, k=-1), sp.eye(ny), format="csc")
        ia = sp.kron(sp.eye(T), sp.csc_matrix(a), format="csc")
        ic = sp.kron(sp.eye(T), sp.csc_matrix(c), format="csc")
        ih = sp.kron(sp.eye(T), sp.csc_matrix(h), format="csc")
        W0, W1 = W[:, :ny], W[:, ny:]
        cons = [
            X[:, :nx] == np.eye(nx),
            X @ zx - a @ X - b @ U == 0,
            X @ zx - X @ ia - Y @ ic == 0,
            U[:, :nx] == W0 @ c,
            U @ zx - U @ ia - W1 @ ic == 0,
        ]
        if not self.drops_redundant:
            cons += [Y[:, :ny] == b @ W0, Y @ zy - a @ Y - b @ W1 == 0]
        if s.strictly_proper:
            cons.append(W0 == 0)
        from qsls.pipeline.control.guarantee import (
            error_weights,
            measured_channels,
            outlier_channels,
        )

        measured = measured_channels(s.measure)
        unread = [t * ny + j for t in range(T + 1) for j in range(ny) if j not in measured]
        if unread:  # position-only output feedback: u never reads these channels
            cons.append(W[:, unread] == 0)
        wx = sp.diags(np.asarray(s.state_scale, float))
        inv_e = sp.diags(np.tile(error_weights(s.error_scale, measured), T))
        XH = X @ ih
        n_xy = cp.max(cp.sum(cp.abs(wx @ Y @ inv_e), axis=1))
        n_xx = cp.max(cp.sum(cp.abs(wx @ XH), axis=1))
        g_m = self._sparse_gain(Y, s, outlier_channels(s.measure, s.m), T, ny)
        p: dict[str, Any] = {}
        if s.robust:
            p["c_xy"] = cp.Parameter(nonneg=True, name="S_plus_eps_e_over_r")
            p["c_xx"] = cp.Parameter(nonneg=True, name="eps_w_over_r")
            p["c_rhs"] = cp.Parameter(name="one_minus_delta_over_r")
            lhs = p["c_xy"] * n_xy + p["c_xx"] * n_xx
            if g_m is not None:
                p["c_o"] = cp.Parameter(nonneg=True, name="eps_o_over_r")
                lhs = lhs + p["c_o"] * g_m
            cons.append(lhs <= p["c_rhs"])
            if s.gate:
                cons += self._gate_constraints(X @ ih, Y, s, measured, T, ny, p)
        if isinstance(cost, WeightedCost):
            blocks = {}
            for name, var, rows, right in (
                ("xx", X, nx, ih),
                ("xy", Y, nx, None),
                ("ux", U, nu, ih),
                ("uy", W, nu, None),
            ):
                if s.diagonal_weights:
                    p["L" + name] = cp.Parameter(rows, name="L" + name)
                    weight = cp.diag(p["L" + name])
                else:
                    p["L" + name] = cp.Parameter((rows, rows), name="L" + name)
                    weight = p["L" + name]
                if not cost.imitates:  # c_QR
                    v = var if right is None else var @ right
                    blocks[name] = weight @ v
                else:
                    p["N" + name] = cp.Parameter(var.shape, name="N" + name)
                    blocks[name] = weight @ var - p["N" + name]
            if s.norm == "l1":
                rows_x = cp.sum(cp.abs(blocks["xx"]), axis=1) + cp.sum(cp.abs(blocks["xy"]), axis=1)
                rows_u = cp.sum(cp.abs(blocks["ux"]), axis=1) + cp.sum(cp.abs(blocks["uy"]), axis=1)
                objective = cp.max(cp.hstack([rows_x, rows_u]))
            else:
                objective = sum(cp.sum_squares(v) for v in blocks.values())
        elif isinstance(cost, ErrorGain):
            objective = n_xy
        elif cost == RATIO:  # Dinkelbach: min lambda N + (eps_w / r) N_w + (eps_o / r) G_m
            p["lam"] = cp.Parameter(nonneg=True, name="lambda")
            p["c_xx_ratio"] = cp.Parameter(nonneg=True, name="eps_w_over_r_ratio")
            objective = p["lam"] * n_xy + p["c_xx_ratio"] * n_xx
            if g_m is not None:
                p["c_o_ratio"] = cp.Parameter(nonneg=True, name="eps_o_over_r_ratio")
                objective = objective + p["c_o_ratio"] * g_m
        elif isinstance(cost, NoCost):
            objective = cp.Constant(0.0)  # type: ignore[assignment]
        else:
            raise ValueError(f"unknown cost {s.cost!r}")
        self.params = p
        self.problem = cp.Problem(cp.Minimize(objective), cons)
        self.construct_time_s = time.perf_counter() - t0
        self._compiled = False

    @staticmethod
    def _sparse_gain(Y: Any, s: Structure, channels: tuple[int, ...], T: int, ny: int) -> Any:
        """``G_m`` as a convex expression of ``Phi_xy``'s taps 1..T (None without outliers):
        per state row, the ``m`` largest per-tap sums of ``|Phi_xy(t)_ij|`` over the outlier
        channels (``cp.sum_largest``), weighted by ``W_x``."""
        import cvxpy as cp

        if not channels:
            return None
        rows = [t * ny + j for t in range(T) for j in channels]
        cols = [t for t in range(T) for _ in channels]
        pick = sp.csc_matrix((np.ones(len(rows)), (rows, cols)), shape=(T * ny, T))
        per_tap = cp.abs(Y) @ pick  # (nx, T)
        k = min(s.m, T)
        return cp.max(
            cp.hstack(
                [s.state_scale[i] * cp.sum_largest(per_tap[i, :], k) for i in range(Y.shape[0])]
            )
        )

    @staticmethod
    def _gate_constraints(
        XH: Any, Y: Any, s: Structure, measured: tuple[int, ...], T: int, ny: int, p: dict
    ) -> list:
        """``rho_v <= V`` (:func:`qsls.pipeline.control.guarantee.velocity_deviation`) per
        velocity row: ``eps_w sum|Phi_xx H|_i + (eps + S r) sum|Phi_xy W_e^-1|_i + eps_o G_m,i``."""
        import cvxpy as cp

        from qsls.pipeline.control.guarantee import error_weights, outlier_channels

        p["g_w"] = cp.Parameter(nonneg=True, name="gate_eps_w")
        p["g_d"] = cp.Parameter(nonneg=True, name="gate_eps_plus_S_r")
        p["g_o"] = cp.Parameter(nonneg=True, name="gate_eps_o")
        p["g_V"] = cp.Parameter(nonneg=True, name="gate_V")
        inv_e = sp.diags(np.tile(error_weights(s.error_scale, measured), T))
        channels = outlier_channels(s.measure, s.m)
        out = []
        for i in (3, 4, 5):
            row = p["g_w"] * cp.sum(cp.abs(XH[i, :])) + p["g_d"] * cp.sum(cp.abs(Y[i, :] @ inv_e))
            if channels:
                cols = [t * ny + j for t in range(T) for j in channels]
                per_tap = cp.reshape(cp.abs(Y[i, cols]), (T, len(channels)), order="C")
                row = row + p["g_o"] * cp.sum_largest(cp.sum(per_tap, axis=1), min(s.m, T))
            out.append(row <= p["g_V"])
        return out

    # ---- parameters
    def set_values(self, v: Values) -> None:
        """The premise's Parameters as the eliminated problem sets them; the weights of
        ``c_QR`` and ``c_im`` its own (this formulation's Parameters are not the eliminated
        problem's, which the cost objects set), any other cost's by the cost."""
        self._set_premise(v)
        if isinstance(self.cost, WeightedCost):
            self.set_weights(v)
        else:
            self.cost.set_values(self, self.params, v)

    def set_weights(self, v: Values) -> None:
        s, p = self.structure, self.params
        qh = psd_sqrt(v.Q, "Q")
        rh = psd_sqrt(v.R, "R")
        if not self.cost.imitates:  # c_QR
            n = v.numbers
            w = {"xx": n.eps_w, "xy": n.eps, "ux": n.eps_w, "uy": n.eps}
        else:
            w = dict.fromkeys(("xx", "xy", "ux", "uy"), 1.0)
        for name, half in (("xx", qh), ("xy", qh), ("ux", rh), ("uy", rh)):
            if s.diagonal_weights:
                if not (is_diagonal(v.Q) and is_diagonal(v.R)):
                    raise ValueError("this problem was built for diagonal Q and R")
                p["L" + name].value = w[name] * np.diag(half)
            else:
                p["L" + name].value = w[name] * half
        if self.cost.imitates:
            if v.nominal is None:
                raise ValueError("the imitation cost needs nominal responses")
            n = v.nominal.truncated(s.T)
            p["Nxx"].value = qh @ side_by_side(n.Phi_xx[1:])
            p["Nxy"].value = qh @ side_by_side(n.Phi_xy[1:])
            p["Nux"].value = rh @ side_by_side(n.Phi_ux[1:])
            p["Nuy"].value = rh @ side_by_side(n.Phi_uy)

    def taps(self) -> Taps:
        m = self.model
        nx, nu, ny = m.nx, m.nu, m.ny

        def with_zero(val: Any, cols: int) -> np.ndarray:
            t = from_side_by_side(np.asarray(val), cols)
            return np.concatenate([np.zeros((1, *t.shape[1:])), t])

        uy = from_side_by_side(np.asarray(self.W.value), ny).reshape(-1, nu, ny)
        if self.structure.strictly_proper:
            uy[0] = 0.0  # structurally zero (the solver returns ~1e-19)
        if self.structure.measure == "position":
            uy[:, :, 3:] = 0.0  # never read (the solver returns ~1e-14)
        return Taps(
            Phi_xx=with_zero(self.X.value, nx),
            Phi_ux=with_zero(self.U.value, nx),
            Phi_xy=with_zero(self.Y.value, ny),
            Phi_uy=uy,
        )


class SharedRowsProblem(SLSProblem):
    """A variant measured in issue 37 (benchmarks/bench_synth.py, docs/performance.md) and not
    adopted: ``G_m``'s ``sum_largest`` written out as its LP ``g_i = min_q m q + sum_t
    max(P_it - q, 0)``, one ``g_i`` per row shared by ``G_m`` and the velocity gate, and
    only the rows of positive weight in the maxima. The same optimum, a 5 % smaller conic
    problem, no measurable gain, and another point of the LP's optimal face."""

    def _premise_norms(self) -> PremiseNorms:
        import cvxpy as cp

        s, T = self.structure, self.structure.T
        wx = np.asarray(s.state_scale, float)
        read = np.flatnonzero(wx > 0)
        inv_e = error_weights(s.error_scale, measured_channels(s.measure))
        self._rs_xh = self.sums("Phi_xx_H", lambda t, i, j: 1.0)
        self._rs_xy = self.sums("Phi_xy", lambda t, i, j: inv_e[j])
        n_xy = cp.max(cp.multiply(wx[read], self._rs_xy[read]))
        n_xx = cp.max(cp.multiply(wx[read], self._rs_xh[read]))
        channels = outlier_channels(s.measure, s.m)
        self._g_rows = {}
        if not channels:
            return PremiseNorms(n_xy, n_xx, None)
        rows = sorted(set(read.tolist()) | (set(VELOCITY) if s.gate else set()))
        per_tap = self.sums("Phi_xy", lambda t, i, j: np.isin(j, channels), by_tap=True)
        pick = np.concatenate([np.arange(i * T, (i + 1) * T) for i in rows])
        g = cp.Variable(len(rows))
        q = cp.Variable(len(rows))
        u = cp.Variable((len(rows), T), nonneg=True)
        level = sp.kron(sp.eye(len(rows)), np.ones((T, 1)), format="csr")
        self._cons += [
            cp.vec(u.T, order="F") >= per_tap[pick] - level @ q,
            min(s.m, T) * q + cp.sum(u, axis=1) <= g,
        ]
        self._g_rows = {i: g[n] for n, i in enumerate(rows)}
        pos = [n for n, i in enumerate(rows) if wx[i] > 0]
        g_m = cp.max(cp.multiply(wx[[rows[n] for n in pos]], g[pos]))
        return PremiseNorms(n_xy, n_xx, g_m)
