"""Mirrored axes solved once (issue 37, pipeline/control/achievable.py): the quadrotor's x and y
axes are a signed permutation of each other, so a problem whose weights share that symmetry is
solved on the x and z axes and y is x's mirror image. The same optimum as the problem on every
axis, a symmetric response, the same certificate checks passing; no mirror where the weights
differ between x and y."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from qsls.pipeline.control import certify, sls
from qsls.pipeline.control.achievable import axis_groups, find_mirrors
from qsls.pipeline.core.plant import plant_model, quadrotor_model
from qsls.pipeline.premise.numbers import PremiseNumbers

ATTITUDE = plant_model("attitude", H=np.diag([0.1, 0.1, 0.1, 1, 1, 1]))
HOVER = quadrotor_model()
EXTRA = (0.0,) * 5
# the quickstart's premise shape on the attitude plant: W_e, outliers (G_m), velocity gate
SHAPE = sls.Shape((1.0,) * 6 + EXTRA, (1.0, 1, 1, 0.5, 0.5, 0.5) + (1.0,) * 5, "full", 2, True)
# numbers where the robustness constraint binds at T = 12 (the cost 1.50 instead of 1.21)
VALUES = sls.Values(
    Q=np.diag([10.0, 10, 10, 1, 1, 1] + [1e-6] * 5), R=np.diag([10.0, 10, 1]),
    numbers=PremiseNumbers(eps=0.08, S=0.0, radius=1.5, eps_w=0.03, delta=0.05, eps_o=1.0, gate=1.5),
)  # fmt: skip


@pytest.mark.parametrize("model", [ATTITUDE, HOVER], ids=["attitude", "hover"])
def test_the_mirror_maps_x_onto_y_and_leaves_the_plant_invariant(model):
    (m,) = find_mirrors(model, np.zeros((model.nx, 1)), np.zeros((model.nu, 1)))
    src = np.flatnonzero(m.state >= 0)
    gx, _ = axis_groups(model)
    assert set(gx[src]) == {0} and set(gx[m.state[src]]) == {1}  # x's states onto y's
    assert list(m.state[[0, 3]]) == [1, 4]  # position onto position, velocity onto velocity
    assert list(np.flatnonzero(m.input >= 0)) == [0] and m.input[0] == 1
    # the signed permutation as a matrix on states and on inputs: P A P^T = A, P B Pu^T = B
    P, Pu = np.eye(model.nx), np.eye(model.nu)
    for i in src:
        P[[i, m.state[i]]] = 0.0
        P[m.state[i], i] = P[i, m.state[i]] = m.d_state[i]
    Pu[[0, 1]] = 0.0
    Pu[1, 0] = Pu[0, 1] = m.d_input[0]
    for a, b in ((P @ model.A @ P.T, model.A), (P @ model.B @ Pu.T, model.B)):
        np.testing.assert_array_equal(a, b)
    assert m.d_input[0] == -1.0  # pitch pushes +x as roll pushes -y


def test_weights_that_tell_x_from_y_are_not_mirrored():
    structure = SHAPE.structure(10, "qr", False)
    assert sls.mirrors_of(ATTITUDE, structure, VALUES.Q, VALUES.R)
    q = VALUES.Q.copy()
    q[1, 1] = 5.0
    assert not sls.mirrors_of(ATTITUDE, structure, q, VALUES.R)
    skew = replace(structure, error_scale=(1.0, 2.0, *structure.error_scale[2:]))
    assert not sls.mirrors_of(ATTITUDE, skew)
    sls._CACHE.clear()
    sls.solve(ATTITUDE, structure, replace(VALUES, Q=q))
    assert [s.mirrored for _, s in sls._CACHE] == [False]


@pytest.mark.parametrize("norm", ["l1", "h2"])
def test_mirrored_problem_has_the_same_optimum_and_certificate(norm):
    structure = replace(SHAPE.structure(12, "qr", False), norm=norm, robust=True)
    per_axis = sls.SLSProblem(ATTITUDE, structure)
    full = per_axis.solve(VALUES, solver_options=sls.TIGHT)
    mirrored = sls.SLSProblem(ATTITUDE, replace(structure, mirrored=True))
    # x's 16 entries per tap kept, y's 16 not, z's 9: 25 of 41 free taps
    assert mirrored.mirrors and mirrored.maps.n_free * 41 == per_axis.maps.n_free * 25
    half = mirrored.solve(VALUES, solver_options=sls.TIGHT)
    assert full.status == half.status == "optimal"
    assert half.objective == pytest.approx(full.objective, rel=1e-6)
    (m,) = mirrored.mirrors
    src = np.flatnonzero(m.state >= 0)
    xx = half.taps.Phi_xx
    np.testing.assert_allclose(  # y's block is x's, up to the signs
        xx[:, m.state[src][:, None], m.state[src][None, :]],
        xx[:, src[:, None], src[None, :]] * np.outer(m.d_state[src], m.d_state[src]),
        atol=1e-12,
    )
    numbers = PremiseNumbers(
        eps=VALUES.numbers.eps, S=0.0, radius=1.5, eps_w=0.03, delta=0.05, eps_o=1.0, m=2, gate=1.5
    )
    bodies = [
        certify.certify(s.taps, ATTITUDE, numbers, SHAPE, solver_status="optimal")
        for s in (full, half)
    ]
    for b in bodies:
        assert b.checks and all(c["passed"] for c in b.checks.values()), b.checks
    for name in ("norm_N", "norm_N_w", "robustness_lhs", "rho_v"):
        assert getattr(bodies[1], name) == pytest.approx(getattr(bodies[0], name), rel=1e-6)


@pytest.mark.parametrize(
    ("shape", "cost", "strictly_proper"),
    [
        (sls.Shape(measure="position"), "qr", True),
        (
            sls.Shape((1.0, 1, 2, 0.5, 0.5, 1), (1.0, 1, 1, 4, 4, 2), "full", 2, True),
            "ratio",
            False,
        ),
    ],
    ids=["position-strictly-proper", "weights-outliers-gate-ratio"],
)
def test_mirrored_hover_problems_keep_their_optimum(shape, cost, strictly_proper):
    numbers = PremiseNumbers(
        eps=0.02, S=0.005, radius=1.0, eps_w=0.01, delta=0.05, eps_o=0.02, gate=2.0
    )
    values = sls.Values(numbers=numbers, ratio_lambda=0.1)
    structure = replace(shape.structure(10, cost, strictly_proper), robust=cost == "qr")
    full = sls.SLSProblem(HOVER, structure).solve(values, solver_options=sls.TIGHT)
    half = sls.SLSProblem(HOVER, replace(structure, mirrored=True))
    assert half.mirrors
    sol = half.solve(values, solver_options=sls.TIGHT)
    assert full.status == sol.status == "optimal"
    assert sol.objective == pytest.approx(full.objective, rel=1e-7)
