"""The honest synthesis at the floor (issue 37, second round; docs/synthesis.md, docs/performance.md):
:func:`sls.solve` on the attitude plant leaves out the epigraph rows no norm reads (``W_x``'s zero
rows, a mirror's image rows) and ``c_QR``'s light rows (the extra states, checked after the
solve), and runs Clarabel first without iterative refinement. The same optimum as the problem
with every row at the tight tolerances, every certificate check passing."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from qsls.pipeline.control import certify, sls
from tests.test_sls_mirror import ATTITUDE, SHAPE, VALUES

STRUCTURE = replace(SHAPE.structure(12, "qr", False), robust=True)


def _conic_rows(prob: sls.SLSProblem) -> int:
    return int(prob.problem.get_problem_data("CLARABEL")[0]["A"].shape[0])


def test_solve_leaves_light_rows_out_and_keeps_the_optimum():
    every_row = sls.SLSProblem(ATTITUDE, STRUCTURE)
    full = every_row.solve(VALUES, solver_options=sls.TIGHT)
    sls._CACHE.clear()
    sol = sls.solve(ATTITUDE, STRUCTURE, VALUES)
    ((_, used),) = sls._CACHE  # one solve: the light rows did not bind
    prob = sls._CACHE[(sls._model_key(ATTITUDE), used)]
    assert used.mirrored and used.light_states == (6, 7, 8, 9, 10)
    assert _conic_rows(prob) < 0.75 * _conic_rows(every_row)
    assert full.status == sol.status == "optimal"
    assert sol.objective == pytest.approx(full.objective, rel=1e-6)
    # the full cost (every row, from the taps) is the optimum: the light rows lie below
    qh, rh = sls.psd_sqrt(VALUES.Q, "Q"), sls.psd_sqrt(VALUES.R, "R")
    assert sls.cost_value("l1", sol.taps, ATTITUDE, qh, rh, 0.03, 0.08) == pytest.approx(
        full.objective, rel=1e-6
    )
    numbers = replace(VALUES.numbers, m=2)
    body = certify.certify(sol.taps, ATTITUDE, numbers, SHAPE, solver_status=sol.status)
    assert all(c["passed"] for c in body.checks.values()), body.checks
    assert body.realization_error <= certify.REALIZATION_TOL / 10


def test_a_light_row_above_the_kept_ones_fails_the_check():
    sls._CACHE.clear()
    sol = sls.solve(ATTITUDE, STRUCTURE, VALUES)
    ((_, used),) = sls._CACHE
    assert sls.light_rows_hold(sol.taps, ATTITUDE, VALUES, used)
    # the same taps weighed with the extra states as heavy as position: their rows bind
    q = np.diag([10.0, 10, 10, 1, 1, 1] + [1e4] * 5)
    assert not sls.light_rows_hold(sol.taps, ATTITUDE, replace(VALUES, Q=q), used)
    assert sls.light_states(STRUCTURE, replace(VALUES, Q=q)) == ()
    assert sls.light_states(replace(STRUCTURE, cost="imitation"), VALUES) == ()
