"""The proof's coordinates (docs/guarantee.md, Disturbance in deviation coordinates): from a
tick log alone, the disturbance ``delta_k = dx_{k+1} - A dx_k - B du_k`` and the error the
controller read recompose the flight's deviation exactly, ``x - r = Phi_xx (H w) + Phi_xy e'``
(``H w = delta``, the initial deviation entering as ``delta_{-1}``), and the flight table's
disturbance is that ``delta`` (issue 47)."""

from __future__ import annotations

import numpy as np
import pytest

from qsls.pipeline.core.plant import plant_model
from qsls.pipeline.core.references import Reference, ReferenceOptions
from qsls.pipeline.errormodel.disturbance import (
    deviation_disturbance,
    realized_disturbance,
    shaped_norm,
)
from qsls.pipeline.evaluate.assumptions import gated_errors, signals
from qsls.pipeline.evaluate.certified import certified_premise
from qsls.pipeline.sim.closedloop import fly
from qsls.pipeline.sim.controllers import make_controller
from qsls.pipeline.sim.options import SimOptions
from qsls.pipeline.sim.ticks import tick_log
from tests.controllerfixtures import gated


@pytest.fixture(scope="module")
def flown(tmp_path_factory):
    folder = tmp_path_factory.mktemp("dev") / "l1_gated"
    cdir = gated(folder)
    opts = SimOptions.model_validate(
        {"seed": 3, "duration": 12.0, "controller": {"kind": str(folder)},
         "reference": {"kind": "circle", "radius": 0.5, "period": 6.0, "hold_s": 1.0,
                       "takeoff_s": 1.0, "approach_s": 1.5}}
    )  # fmt: skip
    ctrl = make_controller(opts.controller, opts.vehicle.mass)
    f = fly(opts, ctrl)
    assert not f.crashed
    return cdir, tick_log(f)


def test_the_deviation_recomposes_from_delta_and_the_error_read(flown):
    cdir, log = flown
    taps, model = cdir.controller.taps, cdir.controller.model
    dx = log.x - log.ref
    delta = deviation_disturbance(log.x, log.u, log.ref, log.uff, model.A, model.B,
                                  np.array([0.0, 0.0, model.mass * 9.81]))  # fmt: skip
    e = gated_errors(log, cdir.certificate.gate)
    k_n, T = len(log.t), taps.T
    drive = np.zeros((k_n + 1, 6))  # index j + 1 holds delta_j; index 0 the initial deviation
    drive[0], drive[1:k_n] = dx[0], delta
    rebuilt = np.zeros_like(dx)
    for k in range(k_n):
        for t in range(1, min(T, k + 1) + 1):
            rebuilt[k] += taps.Phi_xx[t] @ drive[k + 1 - t] + taps.Phi_xy[t] @ e[k - t] * (
                k - t >= 0
            )
    err = np.abs(rebuilt - dx).max()
    assert err < 1e-9 * max(1.0, np.abs(dx).max()), err
    # the absolute residual w is not what drives it: it misses the reference's own residual
    w_abs = realized_disturbance(
        log.x, log.u, model.A, model.B, np.array([0, 0, model.mass * 9.81])
    )
    ref_res = w_abs - delta
    r_own = realized_disturbance(log.ref, log.uff, model.A, model.B, np.zeros(3))
    np.testing.assert_allclose(ref_res, r_own, atol=1e-12)


def test_the_flight_tables_disturbance_is_delta_recomputed_from_the_tick_log(flown):
    cdir, log = flown
    c = certified_premise(cdir.folder)
    assert c is not None
    sig = signals(log, c, lambda q: np.zeros(len(q)))
    m = plant_model("hover", cdir.controller.dt, cdir.controller.mass, c.H)
    delta = deviation_disturbance(log.x, log.u, log.ref, log.uff, m.A, m.B, c.u_hover)
    np.testing.assert_array_equal(sig.w, shaped_norm(delta, c.H))


def test_the_model_feedforward_makes_the_reference_nearly_satisfy_the_model():
    ref = Reference(ReferenceOptions())
    t = np.arange(0.0, 25.0, 0.1)
    r = ref.states(t)
    for plant, tol, sampled in (("hover", 1e-3, 0.03), ("attitude", 5e-3, 0.06)):
        m = plant_model(plant, 0.1, 0.256)
        resid = realized_disturbance(
            r, ref.feedforward(t, 0.1, 0.256, plant), m.A, m.B, np.zeros(3)
        )
        assert np.abs(resid).max() < tol
        # the acceleration sampled at the tick, the feedforward before: ten times more
        _, _, a = ref.arrays(t)
        from qsls.pipeline.core.plant import feedforward_input

        old = realized_disturbance(r, feedforward_input(a, 0.256), m.A, m.B, np.zeros(3))
        assert np.abs(old).max() > sampled
