"""``pipeline/evaluate/certified.py`` called directly: the bound's numbers from objects
(``ControllerBound``), the same numbers read back from a real controller folder (a robust L1
solve with its certificate), and the folder checks (names, error-model hash, expansion)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from qsls.pipeline.control import sls
from qsls.pipeline.control.guarantee import Norms, guarantee
from qsls.pipeline.control.status import CERTIFIED, FAILED, RELAXED, SOLVER_INACCURATE
from qsls.pipeline.core.artifacts import sha256_file
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.evaluate.certified import (
    ControllerBound,
    check_model_hash,
    expand_controllers,
    load_bounds,
    load_controller_bound,
)
from qsls.pipeline.premise.numbers import PremiseNumbers
from tests.controllerfixtures import SETTING, synthesized

# S ||Phi_xy|| = 0.1 * 4 = 0.4, a = eps_w ||Phi_xx H|| + Delta = 0.02 * 5 + 0.1 = 0.2
BOUND = ControllerBound(
    name="c", folder=Path("c"), status=CERTIFIED, robust=True,
    numbers=PremiseNumbers(eps=0.05, S=0.1, radius=1.0, eps_w=0.02, delta=0.1, R0=0.04),
    norm_phi_xx_h=5.0, norm_phi_xy=4.0, gamma_certificate=0.1, model_sha256=None,
    robustness_lhs=0.7,
)  # fmt: skip


def test_the_bound_from_numbers():
    b = BOUND
    assert b.denominator == pytest.approx(0.6) and b.finite
    assert b.a_certificate == pytest.approx(0.2)
    assert b.gamma_strict == pytest.approx(0.04 / 0.6)
    # gamma_k = (eps_e + S (eps_w ||Phi_xx H|| + d_k)) / (1 - S ||Phi_xy||)
    d = np.array([0.0, 0.1, 1.0])
    want = (0.05 + 0.1 * (0.1 + d)) / 0.6
    np.testing.assert_allclose(b.gamma_at(d), want, rtol=1e-15)
    np.testing.assert_allclose(b.premise_at(d), 0.05 + 0.1 * d, rtol=1e-15)
    assert b.has_guarantee and b.no_guarantee_reason is None


@pytest.mark.parametrize(
    "change, reason",
    [
        ({"norm_phi_xy": 10.0}, "S*||Phi_xy|| = 1 >= 1"),
        ({"status": FAILED}, "certificate status 'failed'"),
        ({"status": SOLVER_INACCURATE}, "certificate status 'solver_inaccurate'"),
        ({"robustness_lhs": 1.2}, "robustness condition not met (lhs 1.2 >= 1)"),
    ],
)
def test_why_a_controller_has_no_guarantee(change, reason):
    b = dataclasses.replace(BOUND, **change)
    assert b.no_guarantee_reason == reason and not b.has_guarantee
    if not b.finite:
        assert b.gamma_strict == math.inf and np.isinf(b.gamma_at(np.zeros(2))).all()


def _save(cdir, folder: Path) -> Path:
    cdir.controller.save(folder)
    cdir.certificate.save(folder)
    return folder


@pytest.fixture(scope="module")
def robust():
    return synthesized(T=8)


def test_a_controller_folder_gives_the_certificates_gamma_from_its_own_taps(tmp_path, robust):
    b = load_controller_bound(_save(robust, tmp_path / "synth" / "l1_robust"))
    taps = robust.controller.taps
    assert (b.name, b.status, b.robust) == ("l1_robust", RELAXED, True)  # not calibrated
    assert b.norm_phi_xy == pytest.approx(sls.l1_norm(taps.Phi_xy), rel=1e-12)
    assert b.norm_phi_xx_h == pytest.approx(sls.l1_norm(taps.Phi_xx), rel=1e-12)
    assert b.phi_xy is not None and b.phi_xy.shape == (9, 6, 6) and b.phi_xy_tail == 0.0
    assert (b.numbers.S, b.numbers.eps, b.numbers.eps_w, b.numbers.delta) == (
        SETTING.S,
        SETTING.eps,
        SETTING.eps_w,
        SETTING.delta,
    )
    # at the a-priori distance Delta the flight bound is the certificate's dense bound
    # eps + S rho* (guarantee.py): (eps + S a) / (1 - S N) with a = eps_w N_w + Delta
    g = guarantee(SETTING, Norms(N=b.norm_phi_xy, N_w=b.norm_phi_xx_h, G_m=0.0))
    assert b.gamma_at(np.array(SETTING.delta)) == pytest.approx(g.dense_bound, rel=1e-12)
    assert b.gamma_at(np.array(SETTING.delta)) == pytest.approx(b.gamma_certificate, rel=1e-9)
    assert b.has_guarantee and b.dt == pytest.approx(robust.controller.dt)


def test_names_are_made_unique_and_a_synth_folder_expands(tmp_path, robust):
    a = _save(robust, tmp_path / "one" / "l1_robust")
    b = _save(robust, tmp_path / "two" / "l1_robust")
    assert [x.name for x in load_bounds([a, b])] == ["one-l1_robust", "two-l1_robust"]
    assert [x.name for x in load_bounds([a])] == ["l1_robust"]
    _save(robust, tmp_path / "one" / "another")
    assert expand_controllers([tmp_path / "one"]) == [tmp_path / "one" / "another", a]
    assert expand_controllers([a]) == [a]
    with pytest.raises(InputError, match=r"no certificate\.yaml"):
        expand_controllers([tmp_path])
    with pytest.raises(InputError, match="no such controller folder"):
        expand_controllers([tmp_path / "missing"])


def test_the_error_model_hash_check(tmp_path):
    model = tmp_path / "fit" / "error_model.yaml"
    model.parent.mkdir()
    model.write_text("eps_e: 0.05\n")
    assert "records no error-model hash" in check_model_hash(BOUND, model, force=False)
    same = dataclasses.replace(BOUND, model_sha256=sha256_file(model))
    assert check_model_hash(same, model, force=False) is None
    other = dataclasses.replace(BOUND, model_sha256="0" * 64)
    with pytest.raises(InputError, match="certified against error model 000000000000"):
        check_model_hash(other, model, force=False)
    assert check_model_hash(other, model, force=True).endswith("(checked anyway: --force)")


def test_premises_the_flight_check_cannot_read_are_refused(robust):
    # a generalized premise bounds the dense part: velocity clipped at beta, weighted by W_e
    from dataclasses import replace

    assert not BOUND.generalized
    g = replace(BOUND, beta=0.2, error_scale=(1, 1, 1, 0.5, 0.5, 0.5))
    e = np.array([[0.05, 0, 0, 0.9, 0, 0], [0.01, 0, 0, 0.1, 0, 0]])
    assert g.generalized
    np.testing.assert_allclose(g.dense(e), [0.1, 0.05])  # 0.5 * min(0.9, 0.2); 0.5 * 0.1
    pos = replace(BOUND, measure="position")
    np.testing.assert_allclose(pos.dense(e), [0.05, 0.01])  # velocity errors are not read
