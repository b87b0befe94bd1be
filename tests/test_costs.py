"""Costs are objects that own their math (issue 49, docs/synthesis.md#costs): a new cost is one
class, and the problem compiles it without knowing it; configs name costs through the one
registry, :data:`qsls.pipeline.control.costs.COSTS`."""

from __future__ import annotations

import ast
import pickle
from dataclasses import replace
from pathlib import Path
from typing import Any, get_args

import cvxpy as cp
import numpy as np
import pytest

from qsls.pipeline.control import costs, sls
from qsls.pipeline.control.options import ProblemOptions
from qsls.pipeline.control.taps import l1_norm
from qsls.pipeline.core.plant import quadrotor_model

MODEL = quadrotor_model()
Q = np.diag([10.0, 10, 10, 1, 1, 1])
R = np.diag([1.0, 1, 0.1])
VALUES = sls.Values(Q=Q, R=R, numbers=replace(sls.NO_PREMISE, eps_w=0.3, eps=0.5))
RESPONSES = {"Phi_xx_H": "x", "Phi_xy": "x", "Phi_ux_H": "u", "Phi_uy": "u"}


class FrobeniusCost(costs.Cost):
    """``|| diag(Q^1/2, R^1/2) [Phi_xx H eps_w, Phi_xy eps_e; Phi_ux H eps_w, Phi_uy eps_e] ||_F``
    over every tap: the H2 norm of the stacked weighted responses (diagonal ``Q``, ``R``)."""

    def objective(self, prob: Any, p: dict[str, Any], norms: Any) -> Any:
        parts = []
        for name in RESPONSES:
            entries = prob.response(name)  # every tap and entry, affine in the free taps
            p["fro_" + name] = cp.Parameter(entries.shape, nonneg=True)
            parts.append(cp.multiply(p["fro_" + name], entries))
        return cp.norm(cp.hstack(parts), 2)

    def set_values(self, prob: Any, p: dict[str, Any], v: Any) -> None:
        for name, rows in RESPONSES.items():
            half = np.sqrt(np.diag(v.Q if rows == "x" else v.R))
            scale = v.numbers.eps_w if name.endswith("_H") else v.numbers.eps
            _, i, _ = getattr(prob.maps, name).entry()
            p["fro_" + name].value = scale * half[i]


def frobenius(taps: sls.Taps, v: sls.Values) -> float:
    """The same norm by numpy, from the taps alone."""
    n, H = v.numbers, MODEL.H
    top = np.sqrt(v.Q) @ np.concatenate([taps.Phi_xx @ H * n.eps_w, taps.Phi_xy * n.eps], axis=2)
    bottom = np.sqrt(v.R) @ np.concatenate([taps.Phi_ux @ H * n.eps_w, taps.Phi_uy * n.eps], axis=2)
    return float(np.sqrt((top**2).sum() + (bottom**2).sum()))


@pytest.mark.parametrize("robust", [False, True])
def test_a_new_cost_is_one_class(monkeypatch, robust):
    """The H2 cost above, passed to a structure as it is and registered by a name: the solved
    objective is the Frobenius norm of the returned taps, and it is c_QR's H2 optimum (the same
    weighted operator, its sum of squares) up to the square root."""
    numbers = replace(VALUES.numbers, S=0.1, radius=1.0, delta=0.05, eps=0.05, eps_w=0.01)
    values = replace(VALUES, numbers=numbers) if robust else VALUES
    sol = sls.solve(MODEL, sls.Structure(10, "h2", FrobeniusCost(), robust), values)
    assert sol.status == "optimal" and sol.taps is not None
    assert sol.objective == pytest.approx(frobenius(sol.taps, values), rel=1e-6)
    qr = sls.solve(MODEL, sls.Structure(10, "h2", costs.QR, robust), values)
    assert sol.objective == pytest.approx(np.sqrt(qr.objective), rel=1e-5)
    assert sol.objective == pytest.approx(costs.QR.value(qr.taps, MODEL, values, "h2"), rel=1e-5)
    # registered, a config's name for it is the cost, and the cost's name is the config's
    monkeypatch.setitem(costs.COSTS, "fro", FrobeniusCost())
    by_name = sls.Structure(10, "h2", "fro", robust)
    assert by_name.cost == FrobeniusCost() and costs.name_of(by_name.cost) == "fro"


def test_a_term_of_the_premise_is_a_cost_too():
    """The smallest disturbance gain ``N_w = ||Phi_xx H||``: its optimum equals the gain
    recomputed from the taps, and no c_QR design has a smaller one."""
    sol = sls.solve(MODEL, sls.Structure(10, "l1", costs.DisturbanceGain(), False), VALUES)
    assert sol.status == "optimal" and sol.taps is not None
    gain = l1_norm(sol.taps.Phi_xx, MODEL.H)
    assert sol.objective == pytest.approx(gain, rel=1e-6)
    qr = sls.solve(MODEL, sls.Structure(10, "l1", costs.QR, False), VALUES)
    assert gain <= l1_norm(qr.taps.Phi_xx, MODEL.H) + 1e-7


def test_the_registry_maps_every_config_name_and_back():
    for name in get_args(ProblemOptions.model_fields["cost"].annotation):
        assert costs.name_of(costs.cost_of(name)) == name
    for name, cost in costs.COSTS.items():
        assert costs.name_of(cost) == name and costs.cost_of(cost) is cost
        assert pickle.loads(pickle.dumps(cost)) == cost  # a sweep's workers key problems by it
    assert (
        costs.LAMBDA * costs.ErrorGain()
        + costs.EPS_W_OVER_R * costs.DisturbanceGain()
        + costs.EPS_B_OVER_R * costs.BiasGain()
        + costs.EPS_O_OVER_R * costs.SparseGain()
    ) == costs.RATIO
    assert costs.RATIO.needs_norms and not costs.RATIO.imitates and costs.IMITATION.imitates
    with pytest.raises(ValueError, match="unknown cost 'nope'; the costs are qr, imitation"):
        costs.cost_of("nope")


def _compared_names(source: str) -> list[str]:
    """String constants compared (``==``, ``!=``, ``in``) that name a registered cost."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Compare):
            for side in [node.left, *node.comparators]:
                for c in ast.walk(side):
                    if isinstance(c, ast.Constant) and c.value in costs.COSTS:
                        found.append(c.value)
    return found


def test_no_cost_is_told_apart_by_its_name():
    """Only the registry knows the names: the synthesis never compares a cost to one."""
    assert _compared_names("if s.cost in ('qr', 'x') or c != 'ratio': pass") == ["qr", "ratio"]
    control = Path(costs.__file__).parent
    found = {
        f.name: names
        for f in sorted(control.glob("*.py"))
        if f.name != "costs.py" and (names := _compared_names(f.read_text()))
    }
    assert found == {}


class InputGain(costs.Cost):
    """``||R^1/2 Phi_ux H||``, the L1 gain from the disturbance to the weighted inputs: the
    largest weighted row sum of the shared epigraph of ``Phi_ux H`` (every input row read)."""

    def epigraph_rows(self, prob: Any) -> dict[str, np.ndarray]:
        return {"Phi_ux_H": np.full(prob.model.nu, True)}

    def objective(self, prob: Any, p: dict[str, Any], norms: Any) -> Any:
        p["r_half"] = cp.Parameter(prob.model.nu, nonneg=True, name="r_half")
        return cp.max(cp.multiply(p["r_half"], prob.sums("Phi_ux_H", lambda t, i, j: 1.0)))

    def set_values(self, prob: Any, p: dict[str, Any], v: Any) -> None:
        p["r_half"].value = np.sqrt(np.diag(v.R))


def input_gain(taps: sls.Taps, R: np.ndarray) -> float:
    return float((np.sqrt(np.diag(R)) * np.abs(taps.Phi_ux @ MODEL.H).sum(axis=(0, 2))).max())


def independent_optimum(T: int, R: np.ndarray, with_error_gain: bool) -> float:
    """The same objective over the four responses as plain cvxpy variables, every
    achievability equation written out tap by tap (``achievability_residuals``'s), no
    elimination, no block pattern, no mirror, no shared epigraph."""
    a, b, c, h = MODEL.A, MODEL.B, MODEL.C, MODEL.H
    nx, nu, ny = MODEL.nx, MODEL.nu, MODEL.ny
    xx = [np.zeros((nx, nx))] + [cp.Variable((nx, nx)) for _ in range(T)]
    ux = [np.zeros((nu, nx))] + [cp.Variable((nu, nx)) for _ in range(T)]
    xy = [np.zeros((nx, ny))] + [cp.Variable((nx, ny)) for _ in range(T)]
    uy = [cp.Variable((nu, ny)) for _ in range(T + 1)]
    end = {"x": np.zeros((nx, nx)), "u": np.zeros((nu, nx)), "y": np.zeros((nx, ny))}
    cons = []
    for k in range(T + 1):
        ident = np.eye(nx) if k == 0 else np.zeros((nx, nx))
        x1 = xx[k + 1] if k < T else end["x"]
        u1 = ux[k + 1] if k < T else end["u"]
        y1 = xy[k + 1] if k < T else end["y"]
        cons += [
            x1 == a @ xx[k] + b @ ux[k] + ident,
            x1 == xx[k] @ a + xy[k] @ c + ident,
            y1 == a @ xy[k] + b @ uy[k],
            u1 == ux[k] @ a + uy[k] @ c,
        ]
    r_half = np.sqrt(np.diag(R))
    rows_u = sum(cp.sum(cp.abs(ux[k] @ h), axis=1) for k in range(1, T + 1))
    objective = cp.max(cp.multiply(r_half, rows_u))
    if with_error_gain:  # N with unit weights and every channel measured
        objective = objective + cp.max(sum(cp.sum(cp.abs(xy[k]), axis=1) for k in range(1, T + 1)))
    prob = cp.Problem(cp.Minimize(objective), cons)
    prob.solve(solver="CLARABEL")
    assert prob.status == cp.OPTIMAL
    return float(prob.value)


def test_a_new_cost_and_its_sum_with_a_premise_gain_reach_the_independent_optimum():
    """A cost the library has never seen, ``||R^1/2 Phi_ux H||``, and its sum with the
    premise's error gain ``N``: ``sls.solve`` (eliminated taps, block pattern, mirror, shared
    epigraphs) reaches the optimum of the plain formulation above, and its taps state it."""
    T = 8
    alone = sls.solve(MODEL, sls.Structure(T, "l1", InputGain(), False), VALUES)
    assert alone.status == "optimal" and alone.taps is not None
    assert alone.objective == pytest.approx(input_gain(alone.taps, R), rel=1e-6)
    assert alone.objective == pytest.approx(independent_optimum(T, R, False), rel=1e-6)
    both = sls.solve(MODEL, sls.Structure(T, "l1", InputGain() + costs.ErrorGain(), False), VALUES)
    assert both.status == "optimal" and both.taps is not None
    stated = input_gain(both.taps, R) + l1_norm(both.taps.Phi_xy)
    assert both.objective == pytest.approx(stated, rel=1e-6)
    assert both.objective == pytest.approx(independent_optimum(T, R, True), rel=1e-6)
    # the sum trades input gain for error gain: it pays more input gain than the first alone
    assert input_gain(both.taps, R) > alone.objective * (1 + 1e-3)
