"""The bound check on held-out flights (qsls evaluate), on inputs with known answers."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from qsls.cli.main import app
from qsls.pipeline.control.artifacts import (
    CERTIFICATE_FILE,
    CONTROLLER_FILE,
    Certificate,
    Controller,
)
from qsls.pipeline.control.sls import l1_norm as fir_inf_norm
from qsls.pipeline.core.artifacts import StageWriter, sha256_file
from qsls.pipeline.core.plant import quadrotor_model
from qsls.pipeline.evaluate.certified import load_controller_bound
from qsls.pipeline.evaluate.figures import smooth
from qsls.pipeline.evaluate.options import EvaluateOptions
from qsls.pipeline.evaluate.stage import evaluate
from qsls.pipeline.evaluate.training import TrainingData
from qsls.pipeline.ingest.flight import X_COLS, make_flight_frame
from qsls.pipeline.premise.numbers import PremiseNumbers
from tests.controllerfixtures import l1_taps, written, written_pd

DT = 0.1


def circle_states(n: int, z: float = 1.0, radius: float = 1.0, period: float = 5.0) -> np.ndarray:
    t = np.arange(n) * DT
    w = 2 * np.pi / period
    x = np.zeros((n, 6))
    x[:, 0] = radius * np.cos(w * t)
    x[:, 1] = radius * np.sin(w * t)
    x[:, 2] = z
    x[:, 3] = -radius * w * np.sin(w * t)
    x[:, 4] = radius * w * np.cos(w * t)
    return x


def write_fit(folder, x_train, e_train, *, eps_e=0.05, s_max=3.0, radius=0.5):
    model = {
        "eps_e": eps_e,
        "radius": radius,
        "state_scale": [1.0] * 6,
        "s_slope": {"max": s_max, "percentiles": {"p95": 0.2}},
        "R0": eps_e,
        "delta": 0.0,
        "n_samples": len(x_train),
        "n_pairs": 10,
    }
    df = pd.DataFrame(x_train, columns=list(X_COLS))
    df.insert(0, "t", np.arange(len(x_train)) * DT)
    df.insert(0, "flight", "train")
    with StageWriter(folder, "fit") as w:
        w.write_yaml("error_model.yaml", model)
        w.write_parquet("training_states.parquet", df)
    return folder / "error_model.yaml"


NUMBERS = PremiseNumbers(eps=0.05, S=0.05, radius=1.0, eps_w=0.01, delta=0.0, R0=0.05)
"""The premise the test controllers are solved and certified under."""


def write_controller(folder, model_file, taps, numbers=NUMBERS, **kw):
    """A real controller folder (``taps`` certified under ``numbers`` and, unless
    ``calibrated=False``, calibrated: status ``certified``) against ``model_file``
    (:func:`tests.controllerfixtures.written`); its numbers are what a reader recomputes."""
    kw.setdefault("error_model_sha256", sha256_file(model_file))
    return written(Path(folder), taps, numbers, **kw)


def explicit_norm(phi: np.ndarray) -> float:
    """``||Phi|| = max_i sum_{t,j} |Phi_ij(t)|``, by explicit sums."""
    return max(float(np.abs(phi[:, i, :]).sum()) for i in range(phi.shape[1]))


def explicit_nominal(x: np.ndarray, e: np.ndarray, phi_xy: np.ndarray) -> np.ndarray:
    """``x_hat_k = x_k - sum_{t=0}^{T} Phi_xy(t) e_{k-t}`` (``e_j = 0`` for ``j < 0``), by loops."""
    x_hat = x.copy()
    for k in range(len(x)):
        for t in range(min(k, len(phi_xy) - 1) + 1):
            x_hat[k] -= phi_xy[t] @ e[k - t]
    return x_hat


def write_flight(folder, x, e):
    stamps = (np.arange(len(x)) * DT * 1e9).astype(np.int64)
    with StageWriter(folder, "ingest") as w:
        w.write_parquet("flight.parquet", make_flight_frame(stamps, x, x + e))
    return folder


@pytest.fixture(scope="module")
def taps():
    """A robust L1 controller (T 8) solved under :data:`NUMBERS`, once per module."""
    return l1_taps(8, NUMBERS)


@pytest.fixture()
def setup(tmp_path, taps):
    rng = np.random.default_rng(0)
    x_train = circle_states(400)
    e_train = rng.uniform(-0.04, 0.04, (400, 6))
    model = write_fit(tmp_path / "fit", x_train, e_train)
    ctrl = write_controller(tmp_path / "l1_robust", model, taps)
    # Held out: the same circle 0.1 m higher (distance exactly 0.1 to the training states),
    # errors 0.03 except a planted spike of 0.2 at sample 37.
    x = circle_states(200, z=1.1)
    e = np.full((200, 6), 0.03)
    e[37, 3] = 0.2
    flight = write_flight(tmp_path / "held_out", x, e)
    return tmp_path, model, ctrl, flight


def test_bounds_match_hand_computation(setup, taps):
    tmp, model, ctrl, flight = setup
    cert = Certificate.load(ctrl)
    assert cert.status == "certified" and cert.S == 0.05 and cert.eps_e == 0.05
    # the certificate's norms are the taps' (H = I), here by explicit sums
    n_xy, n_xx = explicit_norm(taps.Phi_xy), explicit_norm(taps.Phi_xx)
    assert cert.norm_phi_xy == pytest.approx(n_xy, rel=1e-12)
    assert cert.norm_phi_xx_h == pytest.approx(n_xx, rel=1e-12)
    opts = EvaluateOptions(figures=False, flown_by="l1_robust")
    res = evaluate([flight], model, [ctrl], opts, tmp / "ev")
    row = res.table.iloc[0]
    denom = 1 - 0.05 * n_xy
    gamma_strict = 0.05 / denom
    gamma = (0.05 + 0.05 * (0.01 * n_xx + 0.1)) / denom
    assert row["gamma_strict"] == pytest.approx(gamma_strict, rel=1e-12)
    assert row["gamma"] == pytest.approx(gamma, rel=1e-9)
    assert row["max_distance_to_training"] == pytest.approx(0.1, abs=1e-9)
    assert row["max_error_norm"] == pytest.approx(0.2)
    assert row["max_ratio_t"] == pytest.approx(3.7)
    assert row["max_ratio"] == pytest.approx(0.2 / gamma, rel=1e-9)
    # Only the spike exceeds the bounds (0.03 < gamma_strict < gamma < 0.2): one sample of 200.
    assert 0.03 < gamma_strict < gamma < 0.2
    assert row["frac_under_gamma"] == pytest.approx(199 / 200)
    assert row["frac_under_gamma_strict"] == pytest.approx(199 / 200)
    assert not row["local_bound_holds"]
    # 0.2 > eps_e + S d = 0.055: the premise failed on this flight, and the verdict says so.
    assert not row["assumption_holds"]
    assert "premise violated at 0.5% of samples" in row["verdict"]
    assert row["frac_premise_holds"] == pytest.approx(199 / 200)
    # The theorem: x_hat_k = x_k - sum_t Phi_xy(t) e_{k-t}; a_nominal by brute force.
    x = circle_states(200, z=1.1)
    e = np.full((200, 6), 0.03)
    e[37, 3] = 0.2
    x_hat = explicit_nominal(x, e, taps.Phi_xy)
    d_hat = np.abs(x_hat[:, None, :] - circle_states(400)[None]).max(axis=2).min(axis=1)
    a = d_hat.max()
    assert a > row["max_distance_to_training"] + 0.04  # the flown distance does not bound a
    assert row["theorem_applies"] and row["flown_by"] == "l1_robust"
    assert row["a_nominal"] == pytest.approx(a, rel=1e-12)
    assert row["a_nominal_t"] == pytest.approx(DT * int(d_hat.argmax()))
    gamma_nominal = (0.05 + 0.05 * a) / denom
    assert row["gamma_nominal"] == pytest.approx(gamma_nominal, rel=1e-12)
    assert row["nominal_ratio"] == pytest.approx(0.2 / gamma_nominal, rel=1e-12)
    assert bool(row["nominal_within_radius"]) is bool(a < 1.0)
    # the spike exceeds gamma_nominal: the theorem's bound fails where its premise failed
    assert gamma_nominal < 0.2 and not row["bound_holds"]
    assert row["verdict"].startswith("FAILS: max ||e|| 0.2 > gamma_nominal")
    assert "although the premise holds" not in row["verdict"]
    assert row["a_certificate"] == pytest.approx(0.01 * n_xx + 0.0, rel=1e-12)
    doc = json.loads((tmp / "ev" / "evaluation.json").read_text())
    assert doc["controllers"][0]["max_ratio"] == pytest.approx(row["max_ratio"])
    cols = pd.read_parquet(tmp / "ev" / "evaluation.parquet").columns
    for c in (
        "flight",
        "controller",
        "gamma",
        "gamma_strict",
        "max_error_norm",
        "frac_under_gamma",
        "frac_under_gamma_strict",
        "max_ratio",
        "max_ratio_t",
        "max_distance_to_training",
    ):
        assert c in cols


def test_bound_holds_when_errors_small(setup, taps):
    tmp, model, ctrl, _ = setup
    x = circle_states(100, z=1.05)
    e = np.full((100, 6), 0.02)
    flight = write_flight(tmp / "quiet", x, e)
    res = evaluate([flight], model, [ctrl], EvaluateOptions(flown_by="l1_robust"), tmp / "ev2")
    row = res.table.iloc[0]
    assert row["bound_holds"] and row["assumption_holds"]
    assert (
        row["verdict"].startswith("holds: ") and "premise holds at every sample" in row["verdict"]
    )
    # x_hat = x - Phi_xy * e moves each coordinate by at most 0.02 ||Phi_xy|| from the flown
    # state, which is 0.05 above the training circle
    x_hat = explicit_nominal(x, e, taps.Phi_xy)
    d_hat = np.abs(x_hat[:, None, :] - circle_states(400)[None]).max(axis=2).min(axis=1)
    assert row["a_nominal"] == pytest.approx(d_hat.max(), rel=1e-12)
    assert 0.05 < row["a_nominal"] <= 0.05 + 0.02 * explicit_norm(taps.Phi_xy) + 1e-9
    assert row["gamma_nominal"] >= 0.05 > 0.02  # eps_e / (1 - S ||Phi_xy||) at least
    assert row["frac_under_gamma"] == 1.0
    assert (tmp / "ev2" / "perception_error.png").stat().st_size > 1000
    assert (tmp / "ev2" / "distance_to_training.png").is_file()


def test_no_guarantee_when_s_phi_at_least_one(setup, taps):
    tmp, model, _, flight = setup
    # the PD reference (its closed loop's true ||Phi_xy||, about 3.4) under S 0.5
    pd_dir = written_pd(tmp / "pd", replace(NUMBERS, S=0.5), error_model_sha256=sha256_file(model))
    b = load_controller_bound(pd_dir)
    s_norm = 0.5 * b.norm_phi_xy
    assert s_norm >= 1.5 and b.norm_phi_xy == pytest.approx(Certificate.load(pd_dir).norm_phi_xy)
    assert not b.has_guarantee and math.isinf(b.gamma_strict)
    opts = EvaluateOptions(figures=False, flown_by="pd")
    res = evaluate([flight], model, [pd_dir], opts, tmp / "ev3")
    row = res.table.iloc[0]
    assert row["verdict"].startswith(f"no bound: S*||W Phi_xy|| = {s_norm:.3g} >= 1")
    assert math.isinf(row["gamma_nominal"]) and not row["bound_holds"]
    # a recorded flight: the premise only, the theorem's columns empty
    res = evaluate([flight], model, [pd_dir], EvaluateOptions(figures=False), tmp / "ev3b")
    row = res.table.iloc[0]
    assert row["verdict"].startswith("premise only (a recorded flight")
    assert not row["theorem_applies"] and math.isnan(row["gamma_nominal"])
    assert row["bound_holds"] is None
    # finite formula (S ||Phi_xy|| < 1) but the robustness condition not met (eps_e / r = 1
    # at r 0.05): no guarantee, said so
    small = replace(NUMBERS, radius=0.05)
    nom = write_controller(tmp / "nom", model, taps, small, calibrated=False)
    cert = Certificate.load(nom)
    assert cert.status == "uncertified" and cert.robustness_lhs >= 1.0
    b = load_controller_bound(nom)
    assert b.finite and not b.has_guarantee
    res = evaluate([flight], model, [nom], EvaluateOptions(figures=False), tmp / "ev4")
    assert "no guarantee: robustness condition not met" in res.table.iloc[0]["verdict"]
    assert not res.table.iloc[0]["has_guarantee"]
    # a controller whose verification failed is never a guarantee
    bad = write_controller(tmp / "bad", model, taps, calibrated=False, status="failed")
    assert load_controller_bound(bad).no_guarantee_reason == "certificate status 'failed'"


def test_nearest_distance_matches_brute_force():
    rng = np.random.default_rng(3)
    train = rng.normal(size=(500, 6))
    query = rng.normal(size=(50, 6))
    scale = np.array([1, 1, 2, 0.5, 0.5, 1.0])
    d, i = TrainingData.build(train, scale).nearest(query)
    brute = np.abs((query[:, None, :] - train[None]) * scale).max(axis=2)
    np.testing.assert_allclose(d, brute.min(axis=1), rtol=1e-12)
    np.testing.assert_array_equal(i, brute.argmin(axis=1))


def test_fir_norm_and_smoothing():
    taps = np.zeros((3, 2, 2))
    taps[1] = [[1, -2], [0, 1]]
    taps[2] = [[0.5, 0], [-3, 0]]
    assert fir_inf_norm(taps) == pytest.approx(4.0)  # row 1: 0 + 1 + 3 + 0
    y = smooth(np.ones(50), 0.1, 1.0)
    np.testing.assert_allclose(y, 1.0)
    step = smooth(np.r_[np.zeros(1), np.ones(10)], 0.1, 1.0)
    assert step[10] == pytest.approx(1 - math.exp(-1.0), rel=1e-9)


# --------------------------------------------------------------------------- bad input (CLI)
def _run(args):
    return CliRunner().invoke(app, ["evaluate", *map(str, args)])


def test_flight_without_columns_is_one_line_error(setup):
    tmp, model, ctrl, _ = setup
    bad = tmp / "bad_flight"
    with StageWriter(bad, "ingest") as w:
        w.write_parquet("flight.parquet", pd.DataFrame({"t": [0.0, 0.1], "x_px": [0.0, 1.0]}))
    r = _run(["--model", model, "--controller", ctrl, "--flights", bad, "--out", tmp / "o1"])
    assert r.exit_code == 2
    assert "missing columns" in r.output and len(r.output.strip().splitlines()) == 1
    assert not (tmp / "o1").exists()


def test_controller_without_certificate(setup):
    tmp, model, _, flight = setup
    empty = tmp / "empty_ctrl"
    empty.mkdir()
    r = _run(["--model", model, "--controller", empty, "--flights", flight, "--out", tmp / "o2"])
    assert r.exit_code == 2 and "certificate.yaml" in r.output
    assert len(r.output.strip().splitlines()) == 1
    assert not (tmp / "o2").exists()


def test_model_hash_mismatch_refused_then_warned(setup, taps):
    tmp, model, _, flight = setup
    other = write_controller(tmp / "other", model, taps, error_model_sha256="0" * 64)
    r = _run(["--model", model, "--controller", other, "--flights", flight, "--out", tmp / "o3"])
    assert r.exit_code == 2 and "certified against error model" in r.output
    assert "--force" in r.output and not (tmp / "o3").exists()
    r = _run(
        [
            "--model",
            model.parent,
            "--controller",
            other,
            "--flights",
            flight,
            "--out",
            tmp / "o3",
            "--force",
            "--no-figures",
        ]
    )
    assert r.exit_code == 0, r.output
    assert "warning:" in r.output and "certified against error model" in r.output
    doc = json.loads((tmp / "o3" / "evaluation.json").read_text())
    assert any("certified against" in w for w in doc["warnings"])


def test_nonfinite_samples_are_dropped_and_counted(setup, taps):
    tmp, model, ctrl, _ = setup
    x = circle_states(100, z=1.05)
    e = np.full((100, 6), 0.02)
    x[10:15] = np.nan
    flight = write_flight(tmp / "gappy", x, e)
    opts = EvaluateOptions(figures=False, flown_by="l1_robust")
    row = evaluate([flight], model, [ctrl], opts, tmp / "ev5").table.iloc[0]
    assert row["n_samples"] == 95 and row["n_nonfinite_dropped"] == 5
    assert row["frac_under_gamma"] == 1.0 and row["bound_holds"]
    # e_10..e_14 unknown: x_hat_k = x_k - sum_t Phi_xy(t) e_{k-t} is undefined for
    # k = 10 .. 14 + the last nonzero tap (x_10..x_14 unknown too)
    last = max(t for t in range(len(taps.Phi_xy)) if np.any(taps.Phi_xy[t]))
    assert last == 8 and row["n_nominal_undefined"] == 5 + last
    assert "x_hat undefined at 13 samples" in row["verdict"]


def test_same_controller_name_from_two_synth_folders(setup, taps):
    tmp, model, _, flight = setup
    a = write_controller(tmp / "synthA" / "l1_robust", model, taps)
    b = write_controller(tmp / "synthB" / "l1_robust", model, taps, replace(NUMBERS, S=0.1))
    res = evaluate([flight], model, [a, b], EvaluateOptions(figures=False), tmp / "ev6")
    assert list(res.table["controller"]) == ["synthA-l1_robust", "synthB-l1_robust"]
    n = explicit_norm(taps.Phi_xy)  # R0 / (1 - S ||Phi_xy||) at S 0.05 and 0.1
    want = [0.05 / (1 - 0.05 * n), 0.05 / (1 - 0.1 * n)]
    assert list(res.table["gamma_strict"]) == pytest.approx(want, rel=1e-12)


def _filter_bank_controller(folder, model_file, taps):
    """A real filter-bank controller (the robust L1 solve realized), its certified file pair."""
    write_controller(folder, model_file, taps)
    return folder, Controller.load(folder)


def test_tampered_or_foreign_controller_is_refused(setup, taps):
    """A gain changed by 1e-4 (hash updated to match) and a certificate from another controller:
    one line, exit 2, nothing written."""
    tmp, model, _, flight = setup
    good, ctrl = _filter_bank_controller(tmp / "fb", model, taps)
    r = _run(["--model", model, "--controller", good, "--flights", flight, "--out", tmp / "ok"])
    assert r.exit_code == 0, r.output
    # one gain off by 1e-4, the certificate's hash made to match: the gains/taps check catches it
    arrays = ctrl.arrays()
    arrays["K_by"] = arrays["K_by"].copy()
    arrays["K_by"][0, 0] += 1e-4
    from qsls.pipeline.core.artifacts import npz_bytes

    bad = tmp / "tampered"
    bad.mkdir()
    (bad / CONTROLLER_FILE).write_bytes(npz_bytes(arrays))
    cert = Certificate.load(good).model_copy(
        update={"controller_sha256": sha256_file(bad / CONTROLLER_FILE)}
    )
    cert.save(bad)
    r = _run(["--model", model, "--controller", bad, "--flights", flight, "--out", tmp / "o1"])
    assert r.exit_code == 2 and "K_by does not match" in r.output, r.output
    assert len(r.output.strip().splitlines()) == 1 and not (tmp / "o1").exists()
    # the certificate of another controller (the PD reference) beside this controller.npz
    foreign = tmp / "foreign"
    foreign.mkdir()
    (foreign / CONTROLLER_FILE).write_bytes(ctrl.to_bytes())
    written_pd(tmp / "other", NUMBERS, error_model_sha256=sha256_file(model))
    (foreign / CERTIFICATE_FILE).write_bytes((tmp / "other" / CERTIFICATE_FILE).read_bytes())
    r = _run(["--model", model, "--controller", foreign, "--flights", flight, "--out", tmp / "o2"])
    assert r.exit_code == 2 and "is not the controller its certificate.yaml certifies" in r.output
    assert not (tmp / "o2").exists()
    # fly and export refuse both folders the same way, before any work
    for folder, why in ((bad, "K_by does not match"), (foreign, "certificate.yaml certifies")):
        for args in (
            ["fly", "--model", model, "--controller", folder, "--out", tmp / "o3"],
            ["export", folder, "--target", "c", "--out", tmp / "o4"],
        ):
            r = CliRunner().invoke(app, [str(a) for a in args])
            assert r.exit_code == 2 and why in r.output, (args[0], r.output)
            assert len(r.output.strip().splitlines()) == 1
            assert not (tmp / "o3").exists() and not (tmp / "o4").exists()


def _with_matching_hash(folder, source, npz: bytes, **update):
    """``folder`` holding ``npz`` and ``source``'s certificate, its hash made to match."""
    folder.mkdir()
    (folder / CONTROLLER_FILE).write_bytes(npz)
    cert = Certificate.load(source).model_copy(
        update={"controller_sha256": sha256_file(folder / CONTROLLER_FILE), **update}
    )
    cert.save(folder)
    return folder


def test_damaged_altered_pd_or_overclaiming_controllers_are_refused(setup, taps):
    """A truncated or empty controller.npz (with and without a matching hash), a PD whose K
    was changed by 1e-4 (hash updated), and a certificate edited to 'certified' over its own
    violated premise: evaluate, fly and export give one line, exit 2."""
    from qsls.pipeline.control.nominal import pd_responses
    from qsls.pipeline.control.pdgain import PDGains
    from qsls.pipeline.premise.record import Premise, PremiseEntry

    tmp, model, _, flight = setup
    good, ctrl = _filter_bank_controller(tmp / "fb", model, taps)
    raw = ctrl.to_bytes()
    cut = tmp / "cut"  # truncated, certificate unchanged: the hash refuses it before parsing
    cut.mkdir()
    (cut / CONTROLLER_FILE).write_bytes(raw[:5000])
    (cut / CERTIFICATE_FILE).write_bytes((good / CERTIFICATE_FILE).read_bytes())
    cut_hashed = _with_matching_hash(tmp / "cut_hashed", good, raw[:5000])
    empty = _with_matching_hash(tmp / "empty", good, b"")
    K, pd_taps = pd_responses(quadrotor_model(), PDGains(), 10)
    pd_ok = Controller(pd_taps, quadrotor_model(), "static_gain", K)
    assert Controller.load(_with_matching_hash(tmp / "pd", good, pd_ok.to_bytes())).K is not None
    arrays = pd_ok.arrays()
    arrays["K"] = arrays["K"].copy()
    arrays["K"][0, 0] += 1e-4
    from qsls.pipeline.core.artifacts import npz_bytes

    pd_bad = _with_matching_hash(tmp / "pd_bad", good, npz_bytes(arrays))
    relaxed = Premise(
        eps_e=PremiseEntry(value=0.05, chosen="p95", violated=0.05, n_violating=20, n_total=400),
        S=PremiseEntry(value=0.2, chosen="p50", violated=0.5, n_violating=50, n_total=100),
        r=PremiseEntry(value=0.5, chosen="number"),
        Delta=PremiseEntry(value=0.0, chosen="number"),
        eps_w=PremiseEntry(value=0.01, chosen="number"),
        training_data="training_states.parquet",
    )
    over = _with_matching_hash(
        tmp / "over", good, raw, status="certified", premise=relaxed, calibration=None
    )
    cases = (
        (cut, "is not the controller its certificate.yaml certifies"),
        (cut_hashed, "not a readable controller file"),
        (empty, "not a readable controller file"),
        (pd_bad, "gain K does not match"),
        (over, "says 'certified' against its own record"),
    )
    for k, (folder, why) in enumerate(cases):
        for args in (
            ["evaluate", "--model", model, "--controller", folder, "--flights", flight],
            ["fly", "--model", model, "--controller", folder],
            ["export", folder, "--target", "c"],
        ):
            out = tmp / f"o{k}_{args[0]}{len(args)}"
            r = CliRunner().invoke(app, [str(a) for a in [*args, "--out", out]])
            assert r.exit_code == 2 and why in r.output, (folder.name, args[:2], r.output)
            assert len(r.output.strip().splitlines()) == 1 and not out.exists()


def test_silent_mismatches_are_refused_or_warned(setup):
    """A flight at another dt is refused (one line); a training flight given as held out and a
    controller folder without certificate inside a synth folder are warned about, visibly."""
    import shutil

    tmp, model, ctrl, _ = setup
    slow = tmp / "slow"
    stamps = (np.arange(100) * 2 * DT * 1e9).astype(np.int64)
    x = circle_states(100, z=1.1)
    with StageWriter(slow, "ingest") as w:
        w.write_parquet("flight.parquet", make_flight_frame(stamps, x, x + 0.03))
    r = _run(["--model", model, "--controller", ctrl, "--flights", slow, "--out", tmp / "o1"])
    assert r.exit_code == 2 and "sampled every 0.2 s" in r.output and "dt = 0.1" in r.output
    assert len(r.output.strip().splitlines()) == 1 and not (tmp / "o1").exists()
    # the training states flown again, inside a synth folder holding a folder without certificate
    train = write_flight(tmp / "train_again", circle_states(400), np.full((400, 6), 0.01))
    synth = tmp / "synth"
    synth.mkdir()
    shutil.copytree(ctrl, synth / "l1_robust")
    (synth / "half_written").mkdir()
    r = _run(["--model", model, "--controller", synth, "--flights", train, "--out", tmp / "o2"])
    assert r.exit_code == 0, r.output
    assert "looks like a training flight" in r.output
    assert "half_written: no certificate.yaml" in r.output
    ev = json.loads((tmp / "o2" / "evaluation.json").read_text())
    assert any("training flight" in w for w in ev["warnings"])
