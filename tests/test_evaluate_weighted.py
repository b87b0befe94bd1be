"""The bound check of a position-weighted error model (``state_scale`` not all ones, the one
``configs/euroc.yaml`` fits): checked in the model's norms, ``N = ||W_x Phi_xy W_e^-1||`` and
``N_w = ||W_x Phi_xx H||`` (docs/evaluation.md#weighted-error-models), as synthesis states it.
The controller is a real solve in those weights, certified by ``certify()``."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from qsls.pipeline.control import sls
from qsls.pipeline.control.artifacts import (
    CERTIFICATE_FILE,
    CONTROLLER_FILE,
    Certificate,
    Controller,
)
from qsls.pipeline.control.certify import certify
from qsls.pipeline.core.artifacts import StageWriter, sha256_file
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.plant import quadrotor_model
from qsls.pipeline.evaluate.options import EvaluateOptions
from qsls.pipeline.evaluate.stage import evaluate
from qsls.pipeline.premise.numbers import PremiseNumbers
from qsls.pipeline.premise.record import Premise, PremiseEntry
from tests.test_evaluate import circle_states, write_fit, write_flight

SCALE = (1.0, 1.0, 1.0, 0.5, 0.5, 0.5)
NUMBERS = PremiseNumbers(eps=0.05, S=0.05, radius=1.0, eps_w=0.01, delta=0.0, R0=0.05)


def weighted_controller(folder, model_file, state_scale):
    """A robust L1 controller (T 8) solved and certified with the premise in ``state_scale``."""
    model = quadrotor_model()
    shape = sls.Shape(tuple(state_scale))
    st = sls.replace(shape.structure(8, "qr", False), robust=True)
    sol = sls.solve(model, st, sls.Values(numbers=NUMBERS))
    assert sol.taps is not None, sol.solver_status
    body = certify(sol.taps, model, NUMBERS, shape)
    assert body.checks["robustness"]["passed"], body.checks

    def entry(v: float) -> PremiseEntry:
        return PremiseEntry(value=v, chosen="number")

    premise = Premise(
        eps_e=entry(0.05), S=entry(0.05), r=entry(1.0), Delta=entry(0.0), eps_w=entry(0.01),
        state_scale=list(state_scale),
    )  # fmt: skip
    ctrl = Controller(sol.taps, model)
    cert = Certificate.of(
        body, controller="l1_robust", robust=True, norm="l1", cost="qr", strictly_proper=False,
        T=8, dt=model.dt, mass=model.mass, controller_sha256=ctrl.sha256(), S=0.05, eps_e=0.05,
        radius=1.0, delta=0.0, eps_w=0.01, R0=0.05, premise=premise,
        error_model_sha256=sha256_file(model_file),
    )  # fmt: skip
    with StageWriter(folder, "synth") as w:
        w.write_bytes(CONTROLLER_FILE, ctrl.to_bytes())
        w.write_text(CERTIFICATE_FILE, cert.to_yaml())
    return folder, sol.taps


def weighted_norm(phi: np.ndarray, scale) -> float:
    """``max_i sum_{t,j} |w_i Phi_ij(t)|`` over the physical states, by explicit sums."""
    w = np.asarray(scale)
    rows = [w[i] * np.abs(phi[:, i, :]).sum() for i in range(len(w))]
    return float(max(rows))


@pytest.fixture(scope="module")
def weighted(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("weighted")
    rng = np.random.default_rng(0)
    model = write_fit(tmp / "fit", circle_states(400), rng.uniform(-0.04, 0.04, (400, 6)))
    doc = yaml.safe_load(model.read_text())
    doc["state_scale"] = list(SCALE)  # the fit of a position-weighted model, as euroc's
    model.write_text(yaml.safe_dump(doc))
    ctrl, taps = weighted_controller(tmp / "l1_robust", model, SCALE)
    # the training circle 0.1 m higher, velocities 0.3 m/s off: weighted distance 0.15 (0.1 in
    # position, 0.5 * 0.3 in velocity), unweighted 0.3; errors 0.03
    x = circle_states(200, z=1.1)
    x[:, 3] += 0.3
    flight = write_flight(tmp / "held_out", x, np.full((200, 6), 0.03))
    return tmp, model, ctrl, flight, taps, x


def test_a_weighted_model_is_checked_in_its_own_norms(weighted):
    tmp, model, ctrl, flight, taps, x = weighted
    res = evaluate([flight], model, [ctrl], EvaluateOptions(figures=False), tmp / "ev")
    row = res.table.iloc[0]
    n = weighted_norm(taps.Phi_xy[:, :6, :6], SCALE)
    n_w = weighted_norm(taps.Phi_xx[:, :6, :6], SCALE)  # H = I
    assert n < weighted_norm(taps.Phi_xy[:, :6, :6], [1.0] * 6)  # the weights matter here
    assert row["norm_phi_xy"] == pytest.approx(n, rel=1e-9)
    assert row["norm_phi_xx_h"] == pytest.approx(n_w, rel=1e-9)
    w = np.array(SCALE)
    d = (np.abs(x[:, None, :] - circle_states(400)[None]) * w).max(axis=2).min(axis=1)
    assert row["max_distance_to_training"] == pytest.approx(d.max(), abs=1e-12)
    assert d.max() == pytest.approx(0.15, abs=1e-9)
    gamma = (0.05 + 0.05 * (0.01 * n_w + d.max())) / (1 - 0.05 * n)
    assert row["gamma"] == pytest.approx(gamma, rel=1e-9)
    assert row["max_premise_ratio"] == pytest.approx((0.03 / (0.05 + 0.05 * d)).max(), rel=1e-12)
    assert row["assumption_holds"]
    # flown by it: the theorem's ||W Phi_xy|| is the same weighted norm
    own = evaluate([flight], model, [ctrl], EvaluateOptions(figures=False, flown_by="l1_robust"),
                   tmp / "ev_own")  # fmt: skip
    assert own.table.iloc[0]["norm_phi_xy_weighted"] == pytest.approx(n, rel=1e-9)


def test_a_certificate_in_other_weights_than_the_model_is_refused(weighted, tmp_path):
    _, model, _, flight, _, _ = weighted
    ones, _ = weighted_controller(tmp_path / "l1_robust", model, [1.0] * 6)
    with pytest.raises(
        InputError,
        match=r"state_scale \[1.0, 1.0, 1.0, 1.0, 1.0, 1.0\], the error model in \[1.0, 1.0, 1.0, 0.5",
    ):
        evaluate([flight], model, [ones], EvaluateOptions(figures=False), tmp_path / "ev")
