"""The bias term (docs/guarantee.md#the-bias-term): integral action in the synthesis, the
peak gain ``G_b`` in the theorem, the flight's split into one constant bias and the rest, and
the certificate that states them, each checked against an independent computation."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from qsls.pipeline.control import sls
from qsls.pipeline.control.artifacts import Certificate, load_controller_dir
from qsls.pipeline.control.guarantee import bias_gain, guarantee
from qsls.pipeline.control.monitor import NO_MONITOR
from qsls.pipeline.control.realize import RealizedController, filter_bank
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.plant import plant_model
from qsls.pipeline.errormodel.disturbance import split_bias
from qsls.pipeline.export.statement import theorem_lines
from qsls.pipeline.premise.numbers import PremiseNumbers

T = 20
NUMBERS = PremiseNumbers(eps=0.05, S=0.0, radius=1.0, eps_w=0.01, delta=0.05, eps_b=0.5)


@pytest.fixture(scope="module")
def designs() -> dict[bool, tuple[sls.Taps, object]]:
    """The hover plant's robust L1 controller with and without integral action."""
    model = plant_model("hover", dt=0.1)
    out = {}
    for bias in (False, True):
        st = sls.Structure(T, "l1", "qr", True, False, bias=bias)
        sol = sls.solve(model, st, sls.Values(numbers=NUMBERS))
        assert sol.status == "optimal", (bias, sol.solver_status)
        assert sol.taps is not None
        out[bias] = (sol.taps, model)
    return out


def dc_bias_gain(phi_xx_h: np.ndarray, D: np.ndarray) -> float:
    """``max |P_T|`` over the physical rows: 0 with integral action on the bias directions."""
    return float(np.abs((phi_xx_h @ D).sum(axis=0)[:6]).max())


def partial_sum_peak(phi_xx: np.ndarray, D: np.ndarray) -> float:
    """``max_K max_i sum_c |sum_{t<=K} Phi_xx(t) D|_ic``, summed tap by tap in a loop."""
    run = np.zeros((phi_xx.shape[1], D.shape[1]))
    peak = 0.0
    for t in range(phi_xx.shape[0]):
        run = run + phi_xx[t] @ D
        peak = max(peak, float(np.abs(run).sum(axis=1).max()))
    return peak


def test_integral_action_leaves_no_deviation_from_a_constant_bias(designs):
    D = designs[True][1].bias_dirs
    with_, model = designs[True]
    without, _ = designs[False]
    assert dc_bias_gain(with_.Phi_xx @ model.H, D) < 1e-8
    assert dc_bias_gain(without.Phi_xx @ model.H, D) > 0.05  # no integral action: it stays
    # G_b recomputed tap by tap, and what the synthesis bounded
    g_b = bias_gain(with_.Phi_xx @ model.H, D)
    assert g_b == pytest.approx(partial_sum_peak(with_.Phi_xx @ model.H, D), rel=1e-12)
    assert g_b >= model.dt * (1 - 1e-12)  # the first tick's step is D itself: dt on velocity
    lhs = guarantee(NUMBERS, sls.Shape(bias=True).norms(with_, model)).robustness_lhs
    assert lhs < 1.0


def test_the_realized_controller_holds_the_state_within_a_under_bias_and_disturbance(designs):
    """The linear plant with the realized filter bank, a constant bias at eps_b on every axis
    and a disturbance at eps_w with random signs: ``|x - r| <= eps_w N_w + eps_b G_b`` at every
    tick, and once the disturbance stops the bias leaves nothing after T ticks."""
    taps, model = designs[True]
    D = model.bias_dirs
    norms = sls.Shape(bias=True).norms(taps, model)
    bound = NUMBERS.eps_w * norms.N_w + NUMBERS.eps_b * norms.G_b
    rng = np.random.default_rng(3)
    worst = 0.0
    for trial in range(4):
        beta = NUMBERS.eps_b * rng.choice([-1.0, 1.0], 3)
        ctrl = RealizedController(filter_bank(taps), model.dt)
        ctrl.reset(1)
        x = np.zeros((model.nx, 1))
        n = 200
        for k in range(n):
            u = ctrl.step(model.C @ x)
            w = NUMBERS.eps_w * rng.choice([-1.0, 1.0], (model.nx, 1)) if k < n - 3 * T else 0.0
            x = model.A @ x + model.B @ u + model.H @ (D @ beta[:, None] + w)
            worst = max(worst, float(np.abs(x).max()))
        assert np.abs(x).max() < 1e-9, trial  # the bias alone: no deviation left
    assert worst <= bound * (1 + 1e-9)
    assert worst > 0.2 * bound  # the bound is not vacuous here


def test_split_bias_finds_the_injected_constant_and_the_smallest_inflation():
    model = plant_model("hover", dt=0.1)
    D = model.bias_dirs
    rng = np.random.default_rng(0)
    beta = np.array([0.3, -0.2, 0.8])
    noise = rng.uniform(-0.5, 0.5, (300, 6)) * 0.01
    w = beta @ D.T + noise
    split = split_bias(w, D, eps_w=0.01, eps_b=1.0)
    # at the injected beta the ratio is max(0.8 / 1, 0.5 eps_w / eps_w) = 0.8: the minimum is no larger
    assert split.ratio <= 0.8 + 1e-9
    assert np.abs(split.residual).max() <= split.ratio * 0.01 * (1 + 1e-9)
    assert np.abs(split.beta).max() <= split.ratio * 1.0 * (1 + 1e-9)
    assert split.beta[2] == pytest.approx(0.8, abs=0.06)  # z's bias: noise / dt allows 0.05
    # the same flight without a bias term: the constant counts at every tick
    plain = split_bias(w, D, eps_w=0.01, eps_b=0.0)
    assert plain.ratio == pytest.approx(np.abs(w).max() / 0.01)
    assert plain.ratio > 7.0
    # a bias twice the bound breaks the premise by the factor it exceeds it
    over = split_bias(np.tile(2.0 * beta @ D.T, (10, 1)), D, eps_w=0.01, eps_b=0.5)
    assert over.ratio > 1.5


def test_the_certificate_states_the_bias_term_and_refuses_an_edited_gain(tmp_path: Path):
    out = tmp_path / "synth"
    cmd = [sys.executable, "-m", "qsls.cli.main", "synth", "-o", str(out), "--T", "20",
           "--plant", "hover", "--controllers", "single", "--eps-b", "0.5", "--eps-e", "0.05",
           "--S", "0", "--radius", "1", "--delta", "0.05", "--eps-w", "0.01"]  # fmt: skip
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    cert = Certificate.load(out / "l1_robust")
    assert cert.eps_b == 0.5
    assert cert.G_b is not None and cert.G_b >= 0.1 * (1 - 1e-9)
    n = cert.numbers()
    want = n.eps_w * (cert.norm_N_w or 0.0) + n.eps_b * cert.G_b + n.delta
    assert cert.a == pytest.approx(want, rel=1e-12)
    lines = " ".join(theorem_lines(load_controller_dir(out / "l1_robust"), NO_MONITOR))
    assert "eps_b = 0.5 m/s^2" in lines and f"G_b = {cert.G_b:.6g}" in lines
    f = out / "l1_robust" / "certificate.yaml"
    data = yaml.safe_load(f.read_text())
    data["G_b"] = data["G_b"] / 4
    f.write_text(yaml.safe_dump(data, sort_keys=False))
    with pytest.raises(InputError, match="G_b"):
        Certificate.load(out / "l1_robust")


def test_a_certificate_of_an_inaccurate_solve_is_what_its_taps_give(tmp_path: Path):
    """A solve that ends ``optimal_inaccurate`` (cvxpy's word, recorded as ``solver_status``)
    was certified as ``inaccurate`` (the solution's status): recomputed on load, it is the
    same certificate, not a tampered one."""
    from qsls.pipeline.control.artifacts import Controller, recomputation_problems
    from qsls.pipeline.control.certify import certify

    out = tmp_path / "synth"
    cmd = [sys.executable, "-m", "qsls.cli.main", "synth", "-o", str(out), "--T", "12",
           "--plant", "hover", "--controllers", "single", "--eps-e", "0.05", "--S", "0",
           "--radius", "1", "--delta", "0.05", "--eps-w", "0.01"]  # fmt: skip
    assert subprocess.run(cmd, capture_output=True, text=True, timeout=300).returncode == 0
    cert = Certificate.load(out / "l1_robust")
    ctrl = Controller.load(out / "l1_robust")
    body = certify(ctrl.taps, ctrl.model, cert.numbers(), solver_status="inaccurate")
    setting = cert.model_dump(exclude=set(type(body).model_fields))
    redone = Certificate.of(body, **setting | {"solver_status": "optimal_inaccurate"})
    assert redone.status == "solver_inaccurate"
    assert recomputation_problems(redone, ctrl) == []
    # a status the record does not give is still refused
    tampered = redone.model_copy(update={"solver_status": "optimal"})
    assert recomputation_problems(tampered, ctrl)


def test_the_largest_feasible_s_counts_the_bias_term():
    """Dinkelbach's ratio under a premise with a bias term charges ``eps_b G_b``: its ``S_max``
    solves feasible with integral action, 1 % more does not, and it is below the one without
    the bias term."""
    from dataclasses import replace

    from qsls.pipeline.control import largest_s

    model = plant_model("hover", dt=0.1)
    shape = sls.Shape(bias=True)
    given = replace(NUMBERS, S=0.0)
    ms = largest_s.max_feasible_s(model, T, given, shape=shape)
    plain = largest_s.max_feasible_s(model, T, replace(given, eps_b=0.0), shape=sls.Shape())
    assert 0 < ms.s_max < plain.s_max
    st = sls.Structure(T, "l1", "qr", True, False, bias=True)
    at = sls.solve(model, st, sls.Values(numbers=replace(given, S=ms.s_max)))
    assert at.status == "optimal"
    over = sls.solve(model, st, sls.Values(numbers=replace(given, S=1.01 * ms.s_max)))
    assert over.status == "infeasible"
