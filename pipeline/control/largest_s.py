"""The largest feasible ``S`` of a setting (docs/guarantee.md, docs/synthesis.md#sweep): the
robustness constraint ``(S + eps/r) N + (eps_w N_w + Delta + eps_o G_m)/r <= 1 - backoff`` is
satisfiable exactly when ``S <= max rho - eps/r``, ``rho(Phi) = (1 - backoff - Delta/r -
(eps_w N_w + eps_o G_m)/r) / N`` over achievable responses, found by Dinkelbach's method
(:func:`max_ratio`, one run for every ``eps_e``); with a velocity gate ``S_max`` is bisected
below that bound. Also the smallest achievable ``N`` at ``T`` (:func:`min_phi_xy`), which the
diagnosis of an infeasible problem reports and which bounds Dinkelbach's gap."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from qsls.pipeline.control.costs import MIN_ERROR_GAIN, NONE, RATIO
from qsls.pipeline.control.guarantee import largest_slope
from qsls.pipeline.control.sls import (
    ROBUST_BACKOFF,
    Shape,
    Values,
    _model_key,
    solve,
)
from qsls.pipeline.core.errors import SolverError
from qsls.pipeline.core.plant import LinearModel
from qsls.pipeline.premise.numbers import PremiseNumbers

_MIN_XY: dict[tuple, float] = {}


def min_phi_xy(
    model: LinearModel,
    T: int,
    *,
    strictly_proper: bool = False,
    solver: str = "CLARABEL",
    shape: Shape = Shape(),
) -> float:
    """The smallest achievable ``N = ||W_x Phi_xy W_e^-1||`` (induced inf-to-inf) at ``T``
    (solved once per process: a sweep asks for every setting at that ``T``)."""
    key = (_model_key(model), T, strictly_proper, solver, shape)
    if key not in _MIN_XY:
        st = shape.structure(T, MIN_ERROR_GAIN, strictly_proper)
        sol = solve(model, st, Values(), solver=solver)
        if sol.taps is None:
            raise SolverError(f"the smallest-||Phi_xy|| problem failed ({sol.solver_status})")
        _MIN_XY[key] = float(shape.norms(sol.taps, model).N)
    return _MIN_XY[key]


@dataclass(frozen=True)
class MaxRatio:
    """``max rho(Phi)`` over achievable responses (:func:`max_ratio`), with the norms of the
    response that attains it; ``ratio = -inf`` when no response leaves anything for ``S``."""

    ratio: float
    norm_phi_xy: float
    norm_phi_xx: float
    iterations: int
    solve_time_s: float
    gap: float = 0.0
    """``rho(Phi_k) - lam`` at the last step (Dinkelbach's a-posteriori gap; inf when the
    iterations ran out before it closed)."""

    def upper(self, min_norm_phi_xy: float) -> float:
        """An upper bound on the true ``max rho``: the last step minimized
        ``lam N + g`` over every achievable ``Phi``, so ``rho(Phi) <= lam + gap N_k / N(Phi)
        <= lam + gap N_k / min N`` (0 when no response leaves anything for ``S``: then every
        ``Phi`` has ``rho <= 0``); up to the solver's tolerance."""
        if self.ratio == -math.inf:
            return 0.0
        return self.ratio + max(self.gap, 0.0) * self.norm_phi_xy / min_norm_phi_xy


def max_ratio(
    model: LinearModel,
    T: int,
    numbers: PremiseNumbers,
    *,
    strictly_proper: bool = False,
    solver: str = "CLARABEL",
    shape: Shape = Shape(),
    tol: float = 1e-9,
    max_iter: int = 50,
) -> MaxRatio:
    """``max rho(Phi)`` under the premise ``numbers`` (:func:`~qsls.pipeline.control.guarantee.
    largest_slope`: ``rho = (1 - backoff - Delta/r - (eps_w N_w + eps_b G_b + eps_o G_m)/r) /
    N``), by Dinkelbach's method: each step solves ``min lam N + (eps_w/r) N_w + (eps_b/r) G_b
    + (eps_o/r) G_m`` (an LP re-solved through Parameters) and sets ``lam = rho(Phi)``; ``lam``
    increases monotonically and converges superlinearly. The premise's ``eps`` and ``S`` play
    no part: one ratio serves every ``eps_e`` (:func:`max_feasible_s`)."""
    structure = shape.structure(T, RATIO, strictly_proper)
    lam, total, it, gap = 0.0, 0.0, 0, math.inf
    nxy = nxx = float("nan")
    numbers = replace(numbers, eps=0.0, S=0.0)
    for it in range(1, max_iter + 1):
        values = Values(numbers=numbers, ratio_lambda=lam)
        sol = solve(model, structure, values, solver=solver)
        total += sol.solve_time_s
        if sol.taps is None:
            raise SolverError(f"the largest-feasible-S subproblem failed ({sol.solver_status})")
        n = shape.norms(sol.taps, model)
        nxy, nxx = n.N, n.N_w
        new = largest_slope(n, numbers, backoff=ROBUST_BACKOFF)
        if it == 1 and new <= 0:
            # lam = 0 minimized eps_w N_w + eps_o G_m: even then (a + eps_o G_m) / r leaves
            # nothing for S: no S >= 0 is feasible
            return MaxRatio(-math.inf, nxy, nxx, it, total)
        if it > 1 and new - lam <= tol * max(1.0, abs(lam)):
            gap = new - lam
            lam = max(lam, new)
            break
        lam = new if it == 1 else max(lam, new)
    return MaxRatio(lam, nxy, nxx, it, total, gap)


@dataclass(frozen=True)
class MaxS:
    """Largest S for which the robustness constraint is satisfiable (``s_max``), with the
    norms of the response that attains it and the Dinkelbach iterations used."""

    s_max: float
    ratio: float  # max over achievable Phi of (1 - Delta/r - (eps_w N_w + eps_o G_m)/r) / N
    norm_phi_xy: float
    norm_phi_xx: float
    iterations: int
    solve_time_s: float


def max_feasible_s(
    model: LinearModel,
    T: int,
    numbers: PremiseNumbers,
    *,
    strictly_proper: bool = False,
    solver: str = "CLARABEL",
    shape: Shape = Shape(),
    ratio: MaxRatio | None = None,
) -> MaxS:
    """Largest ``S`` with ``(S + eps/r) N + (eps_w N_w + eps_b G_b + Delta + eps_o G_m)/r <= 1 -
    backoff`` satisfiable under the premise ``numbers`` (its own ``S`` aside;
    docs/guarantee.md): ``S_max = max rho - eps / r`` (:func:`max_ratio`, or ``ratio`` when
    given: computed for the same setting but any ``eps_e``). The answer is rounded down by a
    relative ``1e-7`` so that ``S_max`` itself solves as feasible. With a velocity gate ``S``
    enters the gate's constraint too: ``S_max`` is then bisected on feasibility below that
    bound."""
    eps_e, radius = numbers.eps, numbers.radius
    r = ratio or max_ratio(
        model, T, numbers, strictly_proper=strictly_proper, solver=solver, shape=shape
    )
    lam, nxy, nxx, it, total = r.ratio, r.norm_phi_xy, r.norm_phi_xx, r.iterations, r.solve_time_s
    if lam == -math.inf:
        return MaxS(-math.inf, lam, nxy, nxx, it, total)
    s_max = lam - eps_e / radius
    s_max -= 1e-7 * max(abs(s_max), 1e-3)
    if shape.gate and s_max >= 0:
        gated = replace(shape.structure(T, NONE, strictly_proper), robust=True)

        def feasible(S: float) -> bool:
            at = Values(numbers=replace(numbers, S=S))
            return solve(model, gated, at, solver=solver).status == "optimal"

        lo, hi = 0.0, s_max
        if not feasible(lo):
            return MaxS(-math.inf, lam, nxy, nxx, it, total)
        if not feasible(hi):
            for _ in range(30):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if feasible(mid) else (lo, mid)
                if hi - lo <= 1e-6 * max(hi, 1e-3):
                    break
            s_max = lo
    return MaxS(s_max, lam, nxy, nxx, it, total)
