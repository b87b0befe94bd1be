"""``pipeline/export/bank.py`` called directly, objects in and objects out: the exported tap
layout against the realization, sizes against independent counts (and gcc's ``sizeof``), the
facts and the certificate gate's words."""

from __future__ import annotations

import dataclasses
import subprocess
from pathlib import Path

import numpy as np
import pytest

from qsls.pipeline.control.artifacts import Controller, ControllerDir
from qsls.pipeline.control.nominal import pd_responses
from qsls.pipeline.control.pdgain import PDGains
from qsls.pipeline.control.realize import RealizedController
from qsls.pipeline.control.sls import Taps
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.plant import quadrotor_model
from qsls.pipeline.export import bank as B
from qsls.pipeline.export.c import c_files
from tests.controllerfixtures import independent_bank, synthesized

T = 8


@pytest.fixture(scope="module")
def proper(tmp_path_factory: pytest.TempPathFactory) -> ControllerDir:
    return synthesized(T, strictly_proper=False, calibrated=tmp_path_factory.mktemp("proper"))


@pytest.fixture(scope="module")
def strict(tmp_path_factory: pytest.TempPathFactory) -> ControllerDir:
    return synthesized(
        T, strictly_proper=True, name="l1_strict", calibrated=tmp_path_factory.mktemp("strict")
    )


def run_bank(bank: B.ExportBank, ys: np.ndarray) -> np.ndarray:
    """The bank's own docstring formula on its own arrays (newest first, zero history)."""
    nx = bank.nx
    betas: list[np.ndarray] = []  # beta[k], beta[k-1], ...
    past: list[np.ndarray] = []  # y[k], y[k-1], ...
    out = []
    for y in ys:
        past.insert(0, y)
        u = sum((bank.ux[j] @ betas[j] for j in range(min(bank.T, len(betas)))), np.zeros(bank.nu))
        u = u + sum(
            bank.uy[j] @ past[bank.uy_first + j]
            for j in range(bank.uy.shape[0])
            if bank.uy_first + j < len(past)
        )
        nb = sum(bank.by[j] @ past[j] for j in range(min(bank.T, len(past))))
        nb = nb + sum(
            (bank.bb[j] @ betas[j] for j in range(min(bank.T - 1, len(betas)))), np.zeros(nx)
        )
        betas.insert(0, nb)
        out.append(u)
    return np.array(out)


@pytest.mark.parametrize("which", ["proper", "strict"])
def test_layout_is_the_realization(which, request):
    cdir: ControllerDir = request.getfixturevalue(which)
    taps = cdir.controller.taps
    bank = B.export_bank(cdir)
    first = 1 if which == "strict" else 0
    assert bank.uy_first == first and bank.T == T
    assert (bank.nx, bank.ny, bank.nu) == (6, 6, 3)
    assert bank.uy.shape == (T + 1 - first, 3, 6) and bank.ux.shape == (T, 3, 6)
    assert bank.bb.shape == (T - 1, 6, 6) and bank.by.shape == (T, 6, 6)
    # signs: bb = -Phi_xx(2..T), by = -Phi_xy(1..T)
    np.testing.assert_array_equal(bank.bb[0], -taps.Phi_xx[2])
    np.testing.assert_array_equal(bank.by[-1], -taps.Phi_xy[T])
    np.testing.assert_array_equal(bank.uy[0], taps.Phi_uy[first])
    ys = np.random.default_rng(3).uniform(-1, 1, (60, 6))
    want = independent_bank(taps, ys)
    got = run_bank(bank, ys)
    rt = RealizedController(cdir.controller.bank, cdir.controller.dt)
    realized = np.array([rt.step(y) for y in ys])
    assert np.abs(want).max() > 1.0
    assert np.abs(got - want).max() <= 1e-12
    assert np.abs(realized - want).max() <= 1e-12
    if which == "strict":  # y[k] does not reach u[k]
        assert np.all(got[0] == 0.0)


def test_counts_and_sizes_against_independent_counts(proper, strict):
    for cdir, first in ((proper, 0), (strict, 1)):
        bank = B.export_bank(cdir)
        # by hand: Phi_uy (T+1-first taps of 3x6), Phi_ux (T of 3x6), Phi_xx (T-1 of 6x6), Phi_xy (T of 6x6)
        n = 18 * (T + 1 - first) + 18 * T + 36 * (T - 1) + 36 * T
        assert bank.constants() == n == (846 if first == 0 else 828)
        assert bank.multiply_adds() == n
        d, f = B.sizes(bank, "double"), B.sizes(bank, "float")
        # two ring heads, the monitor's T + 5 counters and the refusal count (unsigned int),
        # padded to the real
        assert d.state_bytes == (T * 6 + (T + 1) * 6) * 8 + (2 + T + 5 + 1) * 4 == 880
        assert f.state_bytes == (T * 6 + (T + 1) * 6) * 4 + (2 + T + 5 + 1) * 4 == 472
        assert (d.const_bytes, f.const_bytes) == (8 * n, 4 * n)
        assert d.flops_per_tick == f.flops_per_tick == 2 * n
        shares = d.as_dict()
        assert shares["state_share_of_192KB_ram"] == 880 / (192 * 1024)
        assert shares["const_share_of_1MB_flash"] == 8 * n / (1024 * 1024)


def _c_sizeof(
    tmp_path: Path, bank: B.ExportBank, facts: B.ExportFacts, precision: B.Precision
) -> int:
    files = c_files(bank, facts, "szt", precision)
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    (tmp_path / "main.c").write_text(
        '#include <stdio.h>\n#include "szt.h"\nint main(void) { printf("%lu\\n", '
        "(unsigned long)sizeof(szt_t)); return 0; }\n"
    )
    exe = tmp_path / "sz"
    res = subprocess.run(
        ["gcc", "-std=c99", "-Wall", "-Werror", "-o", str(exe), str(tmp_path / "main.c")],
        capture_output=True,
        text=True,
    )
    assert res.returncode == 0, res.stderr
    return int(subprocess.run([str(exe)], capture_output=True, text=True, check=True).stdout)


@pytest.mark.parametrize("shape", [(3, 2, 1, 1), (2, 1, 1, 1), (4, 6, 6, 3)])
@pytest.mark.parametrize("precision", ["double", "float"])
def test_state_bytes_are_gccs_sizeof(tmp_path, proper, shape, precision):
    """``sizes()`` against the compiler's own ``sizeof`` of the generated struct, also for odd
    shapes (T nx + (T+1) ny odd: padding decides)."""
    if subprocess.run(["which", "gcc"], capture_output=True).returncode != 0:
        pytest.skip("no gcc")
    Tn, nx, ny, nu = shape
    rng = np.random.default_rng(0)
    bank = B.ExportBank(
        T=Tn,
        uy_first=0,
        uy=rng.normal(size=(Tn + 1, nu, ny)),
        ux=rng.normal(size=(Tn, nu, nx)),
        bb=rng.normal(size=(Tn - 1, nx, nx)),
        by=rng.normal(size=(Tn, nx, ny)),
    )
    fx = B.facts(proper)
    want = _c_sizeof(tmp_path, bank, fx, precision)
    assert fx.innovation.active  # the innovation monitor's fields are counted too
    assert B.sizes(bank, precision, fx.innovation).state_bytes == want


def test_refuses_static_gain_and_nonfinite_taps(proper):
    model = quadrotor_model()
    K, taps = pd_responses(model, PDGains(), T)
    pd = ControllerDir(
        Path("/nowhere/pd"), Controller(taps, model, "static_gain", K), proper.certificate
    )
    with pytest.raises(InputError, match="'pd' is a static gain"):
        B.export_bank(pd)
    bad = proper.controller.taps.Phi_xy.copy()
    bad[3, 1, 2] = np.nan
    broken = dataclasses.replace(
        proper,
        controller=Controller(Taps(**{**proper.controller.taps.arrays(), "Phi_xy": bad}), model),
    )
    with pytest.raises(InputError, match="Phi_xy holds non-finite taps"):
        B.export_bank(broken)


def test_facts_and_the_generalized_theorem(proper, strict):
    """The facts a file states: the theorem in the certificate's numbers (the special case
    W = I, no outliers: gamma = eps + S rho* = (eps + S a) / (1 - S N), recomputed)."""
    f = B.facts(proper)
    c = proper.certificate
    assert (f.name, f.status, f.T, f.strictly_proper) == ("l1_robust", "certified", T, False)
    assert B.facts(strict).strictly_proper is True
    assert f.dt == 0.1 and f.mass == 0.256 and f.sha256 == proper.controller.sha256()
    assert f.gate is None and f.monitor.active
    text = "\n".join(f.statement)
    assert (
        f.statement[0]
        == "CERTIFIED controller l1_robust: the guarantee below holds under its premise"
    )
    a = 0.01 * c.norm_phi_xx_h + 0.05
    gamma = (0.05 + 0.05 * a) / (1 - 0.05 * c.norm_phi_xy)
    assert c.gamma == pytest.approx(gamma, rel=1e-12)
    assert f"|d_k|_e <= gamma = eps + S rho* = {gamma:.6g}" in text
    assert "eps = 0.05, S = 0.05, r = 1" in text and "Delta = 0.05" in text
    assert "eps_w = 0.01, H = diag(1, 1, 1, 1, 1, 1), eps_w from: not recorded" in text
    assert "with o = 0 (no sparse part)" in text and "gate:" not in text
    assert f"tested range: the calibration flights reached dist {c.tested_range:.6g}" in text
    assert "calibration: 20 flights flown by this controller (conformal); alpha 0.1" in text


def test_gate_words_for_each_status(proper):
    c = proper.certificate
    assert B.status_reason(c) == f"robustness_lhs = {c.robustness_lhs:.6g} < 1, all checks passed"
    B.check_exportable(proper, allow_uncertified=False)  # certified: no error

    failing = {**c.checks, "robustness": {**c.checks["robustness"], "passed": False}}
    unc = c.model_copy(update={"status": "uncertified", "robustness_lhs": 1.25, "checks": failing})
    assert B.status_reason(unc) == "robustness condition fails: robustness_lhs = 1.25 >= 1"
    from qsls.pipeline.export.statement import first_line

    assert first_line(unc, B.status_reason(unc)) == (
        "NOT CERTIFIED (status uncertified, exported with --allow-uncertified): NO GUARANTEE; "
        "missing: robustness condition fails: robustness_lhs = 1.25 >= 1"
    )
    d = dataclasses.replace(proper, certificate=unc)
    with pytest.raises(InputError, match=r"status is 'uncertified'.*--allow-uncertified"):
        B.check_exportable(d, allow_uncertified=False)
    B.check_exportable(d, allow_uncertified=True)

    failed = {**c.checks, "realization": {**c.checks["realization"], "passed": False}}
    bad = c.model_copy(update={"status": "failed", "checks": failed})
    assert B.status_reason(bad) == "failed checks: realization"

    relaxed = c.model_copy(update={"status": "relaxed"})
    assert first_line(relaxed, B.status_reason(relaxed)).endswith(
        "part of the training data lies outside it); this is not plainly certified: premise "
        "shares not recorded"
    )
    assert "not plainly certified" in B.status_reason(relaxed)
    with pytest.raises(InputError, match="relaxed"):
        B.check_exportable(
            dataclasses.replace(proper, certificate=relaxed), allow_uncertified=False
        )

    ref = c.model_copy(update={"status": "reference"})
    assert B.status_reason(ref) == "a reference controller (not synthesized), with no guarantee"


def test_a_gated_certificate_exports_with_its_gate(tmp_path):
    """The exported step applies the gate, so a gated certified controller needs no flag and its
    facts carry the gate."""
    d = synthesized(calibrated=tmp_path)
    gated = d.certificate.model_copy(update={"gate": 1.5})
    cdir = dataclasses.replace(d, certificate=gated)
    B.check_exportable(cdir, allow_uncertified=False)
    assert B.facts(cdir).gate == 1.5


def test_the_header_states_the_reference_and_vehicle_the_calibration_flew() -> None:
    """A certificate says nothing about another reference family or vehicle: the export's
    statement names them in full, not only the flat conditions."""
    from qsls.pipeline.control.artifacts import Calibration
    from qsls.pipeline.export.statement import _calibration_lines

    cal = Calibration(
        flights=20, alpha=0.1, confidence=None, method="conformal", duration_s=15.0,
        conditions={"estimator": "emulator", "perception": "regular", "ivp": None,
                    "reference": {"kind": "circle", "radius": 1.0, "center": [0.0, 0.5]},
                    "vehicle": {"mass": 0.256, "aero": True}},
        seeds=list(range(20)), scores=[1.0] * 20, lambda_hat=1.0, rank=19, tested_range=0.2,
        nominal={}, parts={}, tolerances={}, holds=True,
    )  # fmt: skip
    (line,) = _calibration_lines(cal)
    assert line.endswith(
        "conditions: estimator emulator, perception regular, reference (kind circle, radius 1, "
        "center [0, 0.5]), vehicle (mass 0.256, aero True)"
    )
