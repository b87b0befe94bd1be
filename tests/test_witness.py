"""The tightest sound test, offline (pipeline/evaluate/witness.py, docs/monitor.md#the-reach-of-
a-sound-monitor): flights that keep the premise at its limits are explained by a witness that
numpy alone checks; a constant break is found, never before it starts and never after the
window monitor (which is sound, so it cannot trip before the exact test); the innovations are
the onboard monitor's."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from qsls.pipeline.control.gate import gated_deviation
from qsls.pipeline.control.innovation import InnovationMonitor
from qsls.pipeline.control.monitor import innovation_of, premise_box_of
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.ticks import FlownLog
from qsls.pipeline.evaluate.assumptions import check_assumptions
from qsls.pipeline.evaluate.certified import premise_of
from qsls.pipeline.evaluate.witness import (
    earliest_break,
    innovations,
    premise_witness,
    witness_flight,
    witness_problems,
)
from qsls.pipeline.export import bank as B
from qsls.pipeline.export.python import load_module, module
from tests.controllerfixtures import at_limits, constant_break, gated

V = 1.5
EPS_W = 0.02


@pytest.fixture(scope="module")
def loop(tmp_path_factory):
    """The quickstart's shape (H, W_e, beta 0.2, gate 1.5, m 3, T 20) at eps_w 0.02, its
    exported Python step, its innovation monitor and its premise per tick."""
    ctrl = gated(tmp_path_factory.mktemp("witness") / "l1_gated", eps_w=EPS_W)
    step = load_module(module(B.export_bank(ctrl), B.facts(ctrl))).Controller()
    return ctrl, step, innovation_of(ctrl), premise_box_of(ctrl)


def _fly(ctrl, step, w, e):
    """The linear closed loop (deviation coordinates, ``u_hover`` 0) flown by the exported step,
    as a tick log, and the bits of the library's innovation monitor at each tick."""
    model = ctrl.controller.model
    spec = innovation_of(ctrl)
    mon, x = InnovationMonitor(spec), np.zeros(6)
    step.reset()
    xs, ys, us, bits = [], [], [], []
    for k in range(len(w)):
        y = x + e[k]
        u = np.asarray(step.step(y), dtype=float)
        dev = gated_deviation(y, V)
        bits.append(mon.step(dev.tolist()))
        mon.command(u.tolist())
        xs.append(x), ys.append(y), us.append(u)
        x = model.A @ x + model.B @ u + model.H @ w[k]
    n = len(w)
    log = FlownLog(np.arange(n) * 0.1, np.array(xs), np.array(ys), np.array(us),
                   np.zeros((n, 6)), np.zeros((n, 3)))  # fmt: skip
    return log, np.array(bits)


INSIDE = 1 - 1e-4
"""A witness is sought within bounds tightened by 1e-6: the flights keep theirs by 1e-4."""


def _at_limits(n, sign, k0, rng, outliers):
    """:func:`tests.controllerfixtures.at_limits`, just inside (:data:`INSIDE`)."""
    w, e = at_limits(n, k0, sign, outliers, rng, EPS_W)
    return INSIDE * w, INSIDE * e


def test_the_innovations_are_the_onboard_monitors(loop):
    ctrl, step, spec, box = loop
    rng = np.random.default_rng(7)
    w, e = _at_limits(60, 1.0, 30, rng, outliers=False)
    log, _ = _fly(ctrl, step, w, e)
    nu = innovations(spec, log, np.zeros(3), V)
    mon = InnovationMonitor(spec)
    dev = gated_deviation(log.y, V)
    for k in range(len(dev)):
        if k:
            np.testing.assert_allclose(mon._innovation(dev[k].tolist()), nu[k - 1], atol=1e-12)
        mon.step(dev[k].tolist())
        mon.command(log.u[k].tolist())
    # the loop's own disturbance and errors give them too: nu = H w + e_{k+1} - A e_k
    A, H = ctrl.controller.model.A, ctrl.controller.model.H
    e_read = np.array(log.y, float) - log.x
    e_read[:, 3:] = dev[:, 3:] - log.x[:, 3:]
    np.testing.assert_allclose(nu, w[:-1] @ H.T + e_read[1:] - e_read[:-1] @ A.T, atol=1e-12)
    assert box.exact and box.m == 3 and box.T == 20


@pytest.mark.parametrize("outliers", [False, True])
def test_flights_at_the_premises_limits_are_explained_by_a_checked_witness(loop, outliers):
    """Four runs of 160 ticks at the premise's limits (the window monitor's worst cases): a
    witness exists and numpy alone finds nothing wrong with it; with outliers it places no more
    than m in any T ticks."""
    ctrl, step, spec, box = loop
    rng = np.random.default_rng(49 + outliers)
    for _ in range(4):
        sign = float(rng.choice([-1.0, 1.0]))
        w, e = _at_limits(160, sign, int(rng.integers(1, 150)), rng, outliers)
        log, bits = _fly(ctrl, step, w, e)
        assert not bits.any()
        nu = innovations(spec, log, np.zeros(3), V)
        wit = premise_witness(nu, box)
        assert wit is not None
        assert witness_problems(wit, nu, box) == []
        assert earliest_break(nu, box) is None


def test_a_witness_that_breaks_a_bound_is_told_by_the_check(loop):
    ctrl, step, spec, box = loop
    w, e = _at_limits(80, 1.0, 40, np.random.default_rng(3), outliers=True)
    log, _ = _fly(ctrl, step, w, e)
    nu = innovations(spec, log, np.zeros(3), V)
    wit = premise_witness(nu, box)
    assert wit is not None and witness_problems(wit, nu, box) == []
    e2 = wit.e.copy()
    e2[10, 0] = box.db[0] + 0.01  # a position error beyond its dense bound
    assert any(
        "dense bound" in p for p in witness_problems(dataclasses.replace(wit, e=e2), nu, box)
    )
    e3 = wit.e.copy()
    e3[10, 3] = box.db[3] + box.eps_o + 0.01  # an outlier beyond eps_o
    assert any(
        "beyond eps_o" in p for p in witness_problems(dataclasses.replace(wit, e=e3), nu, box)
    )
    e4 = wit.e.copy()
    e4[20:24, 4] = box.db[4] + 1e-3  # m + 1 outliers within T, counted from the errors
    assert any("outlier ticks within 20 (m 3)" in p
               for p in witness_problems(dataclasses.replace(wit, e=e4), nu, box))  # fmt: skip


@pytest.mark.parametrize(("f", "k0"), [(0.2, 40), (0.5, 40), (1.0, 0)])
def test_a_constant_break_is_found_after_it_starts_and_no_later_than_the_window_monitor(
    loop, f, k0
):
    """From tick ``k0`` the disturbance on vz is (1 + f) eps_w, the errors at their bound with
    the jump against detection: every prefix before the break is explained, and the first tick
    no flight keeping the premise explains lies after the break and no later than the window
    monitor's first trip (a sound monitor cannot trip before it)."""
    ctrl, step, spec, box = loop
    w, e = constant_break(260, f, k0, EPS_W, seed=int(f * 100))
    e *= INSIDE  # the premise keeps its bounds by 1e-4 before the break
    w[:k0] *= INSIDE
    w[k0:, :5] *= INSIDE
    log, bits = _fly(ctrl, step, w, e)
    nu = innovations(spec, log, np.zeros(3), V)
    tripped = np.flatnonzero(bits)
    assert len(tripped)
    L = earliest_break(nu, box)
    assert L is not None and k0 < L <= tripped[0], (L, tripped[0])
    # the tick before, a flight keeping the premise reads the same: its witness checks out
    wit = premise_witness(nu[: L - 1], box)
    assert wit is not None and witness_problems(wit, nu[: L - 1], box) == []


def test_the_box_is_the_premises_own_set_only_with_diagonal_h_no_bias_and_s_0():
    """A witness speaks for the premise only where the box is exact; a break holds for any
    premise the box contains."""
    from qsls.pipeline.control.innovation import premise_box
    from qsls.pipeline.core.plant import quadrotor_model
    from qsls.pipeline.premise.numbers import PremiseNumbers

    model = quadrotor_model(H=np.diag([0.1, 0.1, 0.1, 1, 1, 1]))
    base = PremiseNumbers(eps=0.1, S=0.0, radius=2.0, eps_w=EPS_W, delta=0.0, eps_o=2.8, m=3)
    kw = dict(dense=0.1, error_scale=(1, 1, 1, 0.5, 0.5, 0.5), measure="full", beta=0.2, T=20)

    def box(numbers, H=model.H):
        return premise_box(model.A, H, numbers, bias_dirs=model.bias_dirs, **kw)

    assert box(base).exact
    np.testing.assert_allclose(box(base).per_tick, [0.002] * 3 + [EPS_W] * 3)
    np.testing.assert_allclose(box(base).db, [0.1] * 3 + [0.2] * 3)
    assert not box(dataclasses.replace(base, S=0.05)).exact
    assert not box(dataclasses.replace(base, eps_b=0.1)).exact
    skew = model.H.copy()
    skew[0, 3] = 0.05
    assert not box(base, skew).exact


def test_a_witness_is_a_flight_the_flight_checks_pass(loop):
    """The witness as a flight (the same readings and commands, its true state the gated reading
    less its errors) keeps the disturbance, dense and outlier assumptions as
    :func:`check_assumptions` reads them; the flight it explains broke none either."""
    ctrl, step, spec, box = loop
    w, e = _at_limits(160, -1.0, 70, np.random.default_rng(11), outliers=True)
    log, _ = _fly(ctrl, step, w, e)
    nu = innovations(spec, log, np.zeros(3), V)
    wit = premise_witness(nu, box)
    assert wit is not None and witness_problems(wit, nu, box) == []
    c = dataclasses.replace(premise_of(ctrl), u_hover=np.zeros(3))

    def no_distance(x):
        return np.zeros(len(x))

    for flight in (log, witness_flight(wit, log, V)):
        row = check_assumptions(flight, c, no_distance)
        assert row["disturbance_holds"] and row["dense_holds"] and row["outliers_holds"], row
    np.testing.assert_allclose(witness_flight(wit, log, V).y, log.y)


def test_a_reading_that_is_not_finite_is_refused_in_one_line(loop):
    ctrl, step, spec, _ = loop
    w, e = _at_limits(30, 1.0, 10, np.random.default_rng(5), outliers=False)
    log, _ = _fly(ctrl, step, w, e)
    y = np.array(log.y)
    y[12, 4] = np.nan
    bad = dataclasses.replace(log, y=y)
    with pytest.raises(InputError, match=r"^the reading at tick 12 \(t = 1.20 s\) is not finite"):
        innovations(spec, bad, np.zeros(3), V)
