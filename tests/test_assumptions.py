"""Every assumption of the guarantee checked on a flown log (qsls.pipeline.evaluate.assumptions):
a linear plant flown by a certified, gated controller, with disturbances and errors inside the
premise (every assumption holds, the bound holds, dist(x) stays within rho*), then with one
assumption broken at a time (the verdict names it, at the right time)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from qsls.pipeline.control import sls
from qsls.pipeline.control.certify import certify
from qsls.pipeline.control.realize import RealizedController, filter_bank
from qsls.pipeline.control.status import RELAXED
from qsls.pipeline.core.plant import GRAVITY, quadrotor_model
from qsls.pipeline.evaluate.assumptions import (
    CertifiedPremise,
    FlownLog,
    check_assumptions,
    gated_errors,
)
from qsls.pipeline.evaluate.training import TrainingData
from qsls.pipeline.fly.bound_finding import finding3_assumptions
from qsls.pipeline.premise.numbers import PremiseNumbers

T, R, V, BETA = 20, 2.0, 1.5, 0.2
H = np.diag([0.1, 0.1, 0.1, 1.0, 1.0, 1.0])
NUMBERS = PremiseNumbers(eps=0.1, S=0.0, radius=R, eps_w=0.01, delta=0.0, eps_o=2 * V - BETA,
                         m=2, gate=V)  # fmt: skip
SHAPE = sls.Shape((1.0,) * 6, (1, 1, 1, 0.5, 0.5, 0.5), "full", 2, True)


@pytest.fixture(scope="module")
def certified():
    model = quadrotor_model(H=H)
    st = sls.replace(SHAPE.structure(T, "qr", False), robust=True)
    sol = sls.solve(model, st, sls.Values(numbers=NUMBERS))
    assert sol.taps is not None, sol.solver_status
    c = certify(sol.taps, model, NUMBERS, SHAPE)
    assert c.status == RELAXED and c.checks["robustness"]["passed"], c.checks
    premise = CertifiedPremise(
        numbers=PremiseNumbers(eps=0.1, S=0.0, radius=R, eps_w=0.01, delta=0.0, m=2,
                               eps_o=NUMBERS.eps_o, gate=V),
        a=c.a, rho_star=c.rho_star, beta=BETA, measure="full", error_scale=SHAPE.error_scale,
        phi_xy=sol.taps.Phi_xy, A=model.A, B=model.B, H=model.H,
        u_hover=np.array([0.0, 0.0, model.mass * GRAVITY]),
    )  # fmt: skip
    return model, sol.taps, premise


def _fly(model, taps, *, w_scale=1.0, outliers=(), K=120, seed=0, bias=0.0):
    """The linear plant around hover at the origin, the realized controller reading
    clip(y_v, +/-V): dense errors at the premise's edge, disturbances H w with ||w|| <= eps_w."""
    rng = np.random.default_rng(seed)
    ctrl = RealizedController(filter_bank(taps), model.dt)
    ctrl.reset()
    hover = np.array([0.0, 0.0, model.mass * GRAVITY])
    x = np.zeros(6)
    t, xs, ys, us = [], [], [], []
    for k in range(K):
        d = rng.choice([-1.0, 1.0], size=6) * np.array([0.05] * 3 + [BETA] * 3) * 0.999
        d[:3] += bias
        e = d.copy()
        if k in outliers:
            e[3:] += np.sign(d[3:]) * 0.5  # beyond beta: an outlier of the premise's size
        y = x + e
        dev = y.copy()
        dev[3:] = np.clip(dev[3:], -V, V)
        u = hover + np.asarray(ctrl.step(dev)).reshape(3)
        t.append(k * model.dt)
        xs.append(x.copy())
        ys.append(y)
        us.append(u)
        w = rng.uniform(-1, 1, 6) * NUMBERS.eps_w * w_scale
        x = model.A @ x + model.B @ (u - hover) + model.H @ w
    return FlownLog(
        np.array(t), np.array(xs), np.array(ys), np.array(us), np.zeros((K, 6)), np.zeros((K, 3))
    )


def _training() -> TrainingData:
    return TrainingData.build(np.zeros((1, 6)), (1.0,) * 6)


def test_inside_the_premise_every_assumption_holds(certified):
    model, taps, premise = certified
    log = _fly(model, taps, outliers=(30, 80))
    row = check_assumptions(log, premise, _training().distance)
    assert row["assumptions_hold"], row["verdict"]
    assert row["first_failed"] == "" and row["bound_held"]
    assert row["disturbance_value"] <= NUMBERS.eps_w + 1e-12
    assert 0 < row["invariance_value"] <= premise.rho_star
    assert row["nominal_value"] <= premise.a + 1e-12
    assert row["outliers_value"] == 1.0  # two outliers, 50 steps apart: one per window
    assert row["verdict"].startswith("every assumption holds")


@pytest.mark.parametrize(
    ("kwargs", "failed", "t_fail"),
    [
        ({"w_scale": 3.0}, "disturbance", 0.0),  # the first step's w is already 3x too large
        ({"outliers": (40, 43, 47)}, "outliers", 4.7),  # three within T = 20 steps, m = 2
        ({"bias": 0.08}, "dense", 0.0),  # a position bias above eps at every sample
    ],
)
def test_a_broken_assumption_is_named_first_with_its_time(certified, kwargs, failed, t_fail):
    model, taps, premise = certified
    log = _fly(model, taps, **kwargs)
    row = check_assumptions(log, premise, _training().distance)
    assert not row["assumptions_hold"]
    assert row["first_failed"] == failed, row["verdict"]
    assert row[f"{failed}_t"] == pytest.approx(t_fail)
    assert f"assumption '{failed}' fails first at t={t_fail:.2f}s" in row["verdict"]


def test_a_crashed_flight_is_never_reported_as_held(certified):
    from qsls.pipeline.evaluate.assumptions import crashed

    model, taps, premise = certified
    row = check_assumptions(_fly(model, taps), premise, _training().distance)
    assert row["assumptions_hold"]
    out = crashed(row, 7.5, "ground")
    assert not out["assumptions_hold"] and out["first_failed"] == "crashed"
    assert out["verdict"].startswith("the flight crashed at t=7.5s (ground)")
    bad = check_assumptions(_fly(model, taps, w_scale=3.0), premise, _training().distance)
    assert crashed(bad, 7.5, "ground")["first_failed"] == "disturbance"  # the cause comes first


def test_gate_clips_what_the_controller_reads():
    log = FlownLog(
        np.zeros(2), np.zeros((2, 6)), np.array([[0, 0, 0, 3.0, -0.5, 0]] * 2), np.zeros((2, 3)),
        np.array([[0, 0, 0, 0.5, 0, 0]] * 2), np.zeros((2, 3)),
    )  # fmt: skip
    e = gated_errors(log, 1.0)
    assert e[0].tolist() == [0, 0, 0, 1.5, -0.5, 0]  # v_ref 0.5 + V 1.0; the other inside
    assert gated_errors(log, None)[0, 3] == 3.0


def test_finding3_is_contradicted_by_any_flight_with_its_interval():
    rows = pd.DataFrame({
        "flight": [f"f{i}" for i in range(10)], "assumptions_hold": [True] * 10,
        "bound_held": [True] * 10, "first_failed": [""] * 10,
    })  # fmt: skip
    ok = finding3_assumptions(rows)
    assert ok["verdict"] == "reproduced" and ok["n_violating"] == 0
    assert ok["ci"][0] == 0.0 and ok["ci"][1] == pytest.approx(1 - 0.025 ** (1 / 10))
    rows.loc[3, ["assumptions_hold", "first_failed"]] = [False, "disturbance"]
    bad = finding3_assumptions(rows)
    assert bad["verdict"] == "contradicted" and bad["effect"] == pytest.approx(0.1)
    assert "f3 (disturbance)" in bad["detail"] and 0.0025 < bad["ci"][0] < 0.003
    assert math.isclose(bad["ci"][1], 0.445, abs_tol=1e-3)


def test_finding3_counts_its_failures_per_status_and_outside_the_calibration():
    """A relaxed certificate promises nothing: finding 3's detail says how many failures are
    a relaxed controller's and how many flights lie outside their certificate's calibration."""
    rows = pd.DataFrame({
        "flight": [f"f{i}" for i in range(6)], "bound_held": [True] * 6,
        "assumptions_hold": [True, True, False, False, False, True],
        "first_failed": ["", "", "dense", "disturbance", "outliers", ""],
        "status": ["certified"] * 3 + ["relaxed"] * 3,
        "outside_calibration": ["", "", "perception degraded, calibrated in regular", "", "", ""],
    })  # fmt: skip
    got = finding3_assumptions(rows)
    assert got["verdict"] == "contradicted" and got["n_violating"] == 3
    assert "3 of 6 flights of the robust controllers break" in got["detail"]
    assert "by status: certified 1 of 3, relaxed 2 of 3" in got["detail"]
    assert "1 of the 3 outside their certificate's calibration" in got["detail"]
