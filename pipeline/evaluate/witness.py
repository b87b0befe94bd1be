"""What any sound monitor could know from a flight's readings (docs/monitor.md, The reach of a
sound monitor): the tightest sound test, offline.

A monitor of what the controller reads and commands is sound when it never trips on a flight
whose premise holds. So it may trip at tick ``L`` only if no flight keeping the premise reads
what this one read up to ``L``. With the premise per tick (:class:`PremiseBox`) the question is
a mixed-integer feasibility problem over the errors ``e_0 .. e_L`` and the outlier ticks ``z``::

    |nu_k,c - (e_{k+1,c} - (A_xx e_k)_c)| <= per_tick_c       (the disturbance delta_k)
    |e_k,c| <= db_c + eps_o outlier_c z_k,  z_k in {0, 1}    (dense, outliers on z_k ticks)
    sum_{j=k}^{k+T-1} z_j <= m                               (at most m in any T ticks)

(``nu`` the innovations, :func:`innovations`). A solution is a *witness*: the errors and
disturbances of a flight that keeps the premise and reads exactly these ``nu``. Where one
exists for the whole flight, no sound monitor of ``y`` and ``u`` can trip on it, whatever its
windows or thresholds; where none exists from tick ``L`` on (:func:`earliest_break`), ``L``
is the earliest any sound monitor can trip, the floor under the window test's delay. A break
holds for any premise the box contains; a witness speaks for the premise only where the box
is its own set (``PremiseBox.exact``), else for the box around it.

The solver keeps its constraints to about 1e-7, so both answers are taken on the safe side: a
witness is sought within bounds tightened by :data:`MARGIN` and then checked with numpy alone
against the exact ones (:func:`witness_problems`, its outliers counted from its errors as the
flight checks count them), and as a flight by the flight checks themselves
(:func:`witness_flight`); a break is claimed only where bounds widened by ``MARGIN`` have no
solution either. HiGHS solves it (``scipy.optimize.milp``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import sparse
from scipy.optimize import Bounds, LinearConstraint, milp

from qsls.pipeline.control.innovation import InnovationSpec, PremiseBox, monitor_reading
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.plant import NX
from qsls.pipeline.core.ticks import FlownLog
from qsls.pipeline.evaluate.assumptions import gated_reading
from qsls.pipeline.premise.honest import window_counts

MARGIN = 1e-6
"""A witness is sought within bounds tightened by this much, a break claimed beyond bounds
widened by it (m or m/s): HiGHS keeps its constraints to about 1e-7."""


@dataclass(frozen=True)
class Witness:
    """A flight that keeps the premise and reads the given innovations: its errors ``e``
    (``(n + 1, 6)``), its outlier ticks ``z`` and its disturbances ``delta`` (``(n, 6)``)."""

    e: np.ndarray
    z: np.ndarray
    delta: np.ndarray


def innovations(
    spec: InnovationSpec, log: FlownLog, u_hover: np.ndarray, gate: float | None
) -> np.ndarray:
    """``nu_k = y'_{k+1} - A_xx y'_k - A_xa a_k - B_x du_k`` (``(n - 1, 6)`` for ``n`` ticks), as
    the onboard monitor forms it (:class:`qsls.pipeline.control.innovation.InnovationMonitor`,
    before its quantization): ``y'`` the gated deviation, ``a_k`` the loop states from the
    controller's own commands (``a_0 = 0``, ``a_{k+1} = A_aa a_k + B_a du_k``). A reading that
    is not finite is refused: the onboard monitor restarts there, so split the flight."""
    d, du = monitor_reading(log, u_hover, gate)
    bad = np.flatnonzero(~np.isfinite(d).all(axis=1))
    if len(bad):
        raise InputError(
            f"the reading at tick {bad[0]} (t = {log.t[bad[0]]:.2f} s) is not finite: the "
            "monitor restarts there; check each part of the flight on its own"
        )
    a_xx, b_x = np.array(spec.a_xx, float), np.array(spec.b_x, float)
    nu = d[1:] - d[:-1] @ a_xx.T - du[:-1] @ b_x.T
    if spec.a_aa:
        a_aa, b_a = np.array(spec.a_aa, float), np.array(spec.b_a, float)
        a = np.zeros((len(d), len(a_aa)))
        for k in range(len(d) - 1):
            a[k + 1] = a_aa @ a[k] + b_a @ du[k]
        nu -= a[:-1] @ np.array(spec.a_xa, float).T
    return np.asarray(nu)


def premise_witness(nu: np.ndarray, box: PremiseBox, margin: float = MARGIN) -> Witness | None:
    """A flight keeping ``box`` (its bounds tightened by ``margin``) that reads ``nu``; None
    where the solver finds none (module docstring)."""
    nu = np.asarray(nu, float)
    x = _solve(nu, box, -margin)
    if x is None:
        return None
    N = len(nu) + 1
    e = x[: N * NX].reshape(N, NX)
    z = np.round(x[N * NX :]).astype(int)
    delta = nu - (e[1:] - e[:-1] @ box.a_xx.T)
    return Witness(e=e, z=z, delta=delta)


def broken(nu: np.ndarray, box: PremiseBox, margin: float = MARGIN) -> bool:
    """No flight keeping ``box`` (its bounds widened by ``margin``) reads ``nu``."""
    return _solve(np.asarray(nu, float), box, margin) is None


def earliest_break(nu: np.ndarray, box: PremiseBox, margin: float = MARGIN) -> int | None:
    """The fewest innovations ``L`` (the readings of ticks ``0 .. L``) that no flight keeping
    the premise reads (:func:`broken`): the earliest tick any sound monitor can trip at; None
    where the whole flight is explained. A prefix of explained readings is explained, so the
    search halves."""
    nu = np.asarray(nu, float)
    if not broken(nu, box, margin):
        return None
    lo, hi = 0, len(nu)  # nu[:lo] explained, nu[:hi] not
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if broken(nu[:mid], box, margin):
            hi = mid
        else:
            lo = mid
    return hi


def witness_problems(w: Witness, nu: np.ndarray, box: PremiseBox) -> list[str]:
    """What keeps ``w`` from being a flight that keeps ``box`` and reads ``nu``, checked with
    numpy alone against the exact bounds (empty: it is one). Its outlier ticks are counted from
    its errors, as the flight checks count them (an error beyond ``db`` on an outlier channel),
    not taken from ``w.z``."""
    out = []
    nu = np.asarray(nu, float)
    delta = nu - (w.e[1:] - w.e[:-1] @ box.a_xx.T)
    if not np.allclose(delta, w.delta, rtol=0, atol=1e-9):
        out.append("its disturbances do not give the innovations")
    if np.any(np.abs(delta) > box.per_tick):
        out.append(f"a disturbance beyond per_tick: {np.abs(delta).max():.6g}")
    mag = np.abs(w.e)
    beyond = mag > box.db
    if np.any(beyond & (box.outlier == 0)):
        out.append(f"an error beyond its dense bound by {(mag - box.db).max():.3g}")
    if np.any(mag > box.db + box.eps_o * box.outlier):
        out.append(f"an outlier beyond eps_o by {(mag - box.db - box.eps_o).max():.3g}")
    placed = beyond[:, box.outlier == 1].any(axis=1)
    counts = window_counts(placed, np.zeros(len(placed), int), box.T)
    if len(placed) and counts.max() > box.m:
        out.append(f"{counts.max()} outlier ticks within {box.T} (m {box.m})")
    return out


def witness_flight(w: Witness, log: FlownLog, gate: float | None) -> FlownLog:
    """The flight ``w`` describes: the same readings, commands, reference and feedforward as
    ``log``, its true state the gated reading less the witness's errors (``x = y' - e``), for
    the flight checks (:func:`qsls.pipeline.evaluate.assumptions.check_assumptions`)."""
    x = gated_reading(log, gate) - w.e
    return FlownLog(log.t, x, np.asarray(log.y, float), log.u, log.ref, log.uff)


def _solve(nu: np.ndarray, box: PremiseBox, margin: float) -> np.ndarray | None:
    """The problem of the module docstring with every bound moved by ``margin``; its solution
    (errors then outlier ticks), or None where it has none. HiGHS fails now and then on these
    problems ("Solve error"); it is asked again without its presolve, then with the bounds
    moved 1e-9 further to the safe side (tighter for a witness, which numpy checks anyway;
    wider for a break, which only makes a break harder to claim)."""
    safer = margin + (1e-9 if margin > 0 else -1e-9)
    attempts: list[tuple[float, dict[str, Any]]] = [
        (margin, {}), (margin, {"presolve": False}), (safer, {})
    ]  # fmt: skip
    message = ""
    for m, options in attempts:
        res = milp(**_problem(nu, box, m), options=options)
        if res.status == 0 and res.x is not None:
            return np.asarray(res.x, float)
        if res.status == 2:
            return None
        message = res.message
    raise RuntimeError(f"the premise's witness problem was not solved: {message}")


def _problem(nu: np.ndarray, box: PremiseBox, margin: float) -> dict[str, Any]:
    """The arguments of ``scipy.optimize.milp`` for :func:`_solve`."""
    n = len(nu)
    N = n + 1
    ne = N * NX
    p = box.per_tick + margin
    db = np.maximum(box.db + margin, 0.0)
    sparse_ticks = box.m > 0 and box.outlier.any()
    # the dynamics rows: e_{k+1,c} - sum_j A_cj e_k,j in [nu_kc - p_c, nu_kc + p_c]
    k, c = np.divmod(np.arange(n * NX), NX)
    rows = [np.arange(n * NX)]
    cols = [(k + 1) * NX + c]
    vals = [np.ones(n * NX)]
    for j in range(NX):
        a = box.a_xx[c, j]
        keep = a != 0
        rows.append(np.arange(n * NX)[keep])
        cols.append((k * NX + j)[keep])
        vals.append(-a[keep])
    dyn = sparse.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
        shape=(n * NX, ne + N),
    )
    flat = nu.reshape(-1)
    pp = np.tile(p, n)
    constraints = [LinearConstraint(dyn, flat - pp, flat + pp)]
    lim = np.tile(db + box.eps_o * box.outlier, N)
    lb = np.concatenate([-lim, np.zeros(N)])
    ub = np.concatenate([lim, np.full(N, 1.0 if sparse_ticks else 0.0)])
    if sparse_ticks:
        oc = np.flatnonzero(box.outlier)
        kk, cc = (v.ravel() for v in np.meshgrid(np.arange(N), oc, indexing="ij"))
        r = np.arange(len(kk))
        # |e_kc| <= db_c + eps_o z_k, as e - eps_o z <= db and e + eps_o z >= -db
        g = sparse.csr_matrix(
            (np.concatenate([np.ones(len(r)), np.full(len(r), -box.eps_o)]),
             (np.concatenate([r, r]), np.concatenate([kk * NX + cc, ne + kk]))),
            shape=(len(r), ne + N),
        )  # fmt: skip
        h = sparse.csr_matrix(
            (np.concatenate([np.ones(len(r)), np.full(len(r), box.eps_o)]),
             (np.concatenate([r, r]), np.concatenate([kk * NX + cc, ne + kk]))),
            shape=(len(r), ne + N),
        )  # fmt: skip
        bound = db[cc]
        constraints += [
            LinearConstraint(g, -np.inf, bound),
            LinearConstraint(h, -bound, np.inf),
        ]
        starts = np.arange(max(N - box.T, 0) + 1)
        w = min(box.T, N)
        win = sparse.csr_matrix(
            (np.ones(len(starts) * w),
             (np.repeat(np.arange(len(starts)), w),
              ne + (starts[:, None] + np.arange(w)[None, :]).ravel())),
            shape=(len(starts), ne + N),
        )  # fmt: skip
        constraints.append(LinearConstraint(win, -np.inf, box.m))
    return {
        "c": np.zeros(ne + N),  # a feasibility problem (an objective on z made HiGHS fail more)
        "integrality": np.concatenate([np.zeros(ne), np.full(N, 1 if sparse_ticks else 0)]),
        "bounds": Bounds(lb, ub),
        "constraints": constraints,
    }
