"""The bound check of a position-weighted error model (``state_scale`` not all ones, the one
``configs/euroc.yaml`` fits): checked in the model's norms, ``N = ||W_x Phi_xy W_e^-1||`` and
``N_w = ||W_x Phi_xx H||`` (docs/evaluation.md#weighted-error-models), as synthesis states it."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from qsls.pipeline.control.artifacts import (
    CERTIFICATE_FILE,
    CONTROLLER_FILE,
    Certificate,
    Controller,
)
from qsls.pipeline.control.premise import Premise, PremiseEntry
from qsls.pipeline.control.sls import Taps
from qsls.pipeline.core.artifacts import StageWriter, sha256_file
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.plant import quadrotor_model
from qsls.pipeline.evaluate.bound import EvaluateOptions, evaluate
from tests.test_evaluate import circle_states, write_fit, write_flight

SCALE = [1.0, 1.0, 1.0, 0.5, 0.5, 0.5]


def weighted_controller(folder, model_file, state_scale):
    """``Phi_xy(1) = diag(1, 1, 1, 4, 4, 4)``, ``Phi_xx(1) = 2 I``: ``||Phi_xy|| = 4`` unweighted,
    ``||W_x Phi_xy|| = max(1, 0.5 * 4) = 2`` in ``SCALE``; S 0.2, eps 0.05, eps_w 0.01."""
    gain = np.diag([1.0, 1.0, 1.0, 4.0, 4.0, 4.0])
    z = np.zeros((6, 6))
    taps = Taps(
        Phi_xx=np.stack([z, 2.0 * np.eye(6), z]), Phi_ux=np.zeros((3, 3, 6)),
        Phi_xy=np.stack([z, gain, z]), Phi_uy=np.zeros((3, 3, 6)),
    )  # fmt: skip
    ctrl = Controller(taps, quadrotor_model())

    def entry(v: float) -> PremiseEntry:
        return PremiseEntry(value=v, chosen="number")

    premise = Premise(
        eps_e=entry(0.05), S=entry(0.2), r=entry(0.5), Delta=entry(0.0), eps_w=entry(0.01),
        state_scale=list(state_scale),
    )  # fmt: skip
    cert = Certificate(
        controller="l1_robust", status="relaxed", status_reason="not calibrated", robust=True,
        strictly_proper=False, T=2, S=0.2, eps_e=0.05, R0=0.05, eps_w=0.01, norm_phi_xx_h=2.0,
        norm_phi_xy=4.0, norm_phi_ux=0.0, norm_phi_uy=0.0, radius=0.5, delta=0.0,
        robustness_lhs=0.5, margin=0.5, s_times_norm_phi_xy=0.4, a=0.02, gamma=0.1,
        gamma_strict=0.1, achievability_residual=0.0, dt=0.1, mass=0.256,
        error_model_sha256=sha256_file(model_file), controller_sha256=ctrl.sha256(),
        premise=premise,
    )  # fmt: skip
    with StageWriter(folder, "synth") as w:
        w.write_bytes(CONTROLLER_FILE, ctrl.to_bytes())
        w.write_text(CERTIFICATE_FILE, cert.to_yaml())
    return folder


@pytest.fixture(scope="module")
def weighted(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("weighted")
    rng = np.random.default_rng(0)
    model = write_fit(tmp / "fit", circle_states(400), rng.uniform(-0.04, 0.04, (400, 6)))
    doc = yaml.safe_load(model.read_text())
    doc["state_scale"] = SCALE  # the fit of a position-weighted model, as configs/euroc.yaml's
    model.write_text(yaml.safe_dump(doc))
    ctrl = weighted_controller(tmp / "l1_robust", model, SCALE)
    # the training circle 0.1 m higher, velocities 0.3 m/s off: weighted distance 0.15 (0.1 in
    # position, 0.5 * 0.3 in velocity), unweighted 0.3; errors 0.03
    x = circle_states(200, z=1.1)
    x[:, 3] += 0.3
    flight = write_flight(tmp / "held_out", x, np.full((200, 6), 0.03))
    return tmp, model, ctrl, flight


def test_a_weighted_model_is_checked_in_its_own_norms(weighted):
    tmp, model, ctrl, flight = weighted
    res = evaluate([flight], model, [ctrl], EvaluateOptions(figures=False), tmp / "ev")
    row = res.table.iloc[0]
    assert row["norm_phi_xy"] == pytest.approx(2.0)  # ||W_x Phi_xy||, not the unweighted 4
    assert row["norm_phi_xx_h"] == pytest.approx(2.0)
    # the weighted distance by brute force: max 0.15 (0.1 in z, 0.5 * 0.3 in v_x)
    x = circle_states(200, z=1.1)
    x[:, 3] += 0.3
    w = np.array(SCALE)
    d = (np.abs(x[:, None, :] - circle_states(400)[None]) * w).max(axis=2).min(axis=1)
    assert row["max_distance_to_training"] == pytest.approx(d.max(), abs=1e-12)
    assert d.max() == pytest.approx(0.15, abs=1e-9)
    assert row["has_guarantee"]  # S N = 0.4 < 1 (0.8 unweighted)
    gamma = (0.05 + 0.2 * (0.01 * 2.0 + d.max())) / (1 - 0.2 * 2.0)
    assert row["gamma"] == pytest.approx(gamma, rel=1e-12)
    assert row["max_premise_ratio"] == pytest.approx((0.03 / (0.05 + 0.2 * d)).max(), rel=1e-12)
    assert row["assumption_holds"]
    # flown by it: the theorem's ||W Phi_xy|| is the same weighted norm
    own = evaluate([flight], model, [ctrl], EvaluateOptions(figures=False, flown_by="l1_robust"),
                   tmp / "ev_own")  # fmt: skip
    assert own.table.iloc[0]["norm_phi_xy_weighted"] == pytest.approx(2.0)


def test_a_certificate_in_other_weights_than_the_model_is_refused(weighted, tmp_path):
    _, model, _, flight = weighted
    ones = weighted_controller(tmp_path / "l1_robust", model, [1.0] * 6)
    with pytest.raises(
        InputError,
        match=r"state_scale \[1.0, 1.0, 1.0, 1.0, 1.0, 1.0\], the error model in \[1.0, 1.0, 1.0, 0.5",
    ):
        evaluate([flight], model, [ones], EvaluateOptions(figures=False), tmp_path / "ev")
