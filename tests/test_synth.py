"""`qsls synth`: controllers, certificates, infeasibility, bad input (through the CLI)."""

from __future__ import annotations

import re

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from qsls.cli.main import app
from qsls.pipeline.control import largest_s, sls
from qsls.pipeline.control.artifacts import load_runtime as load_controller
from qsls.pipeline.control.pdgain import PDGains, pd_gain
from qsls.pipeline.control.synth import SynthOptions, max_feasible_s
from qsls.pipeline.core.artifacts import dump_yaml, sha256_file
from qsls.pipeline.core.plant import quadrotor_model
from qsls.pipeline.errormodel.model import DisturbanceStats, ErrorModel, SlopeStats
from qsls.pipeline.premise.choose import ModelInput

RUN = CliRunner()
T = 12


@pytest.fixture
def error_model(tmp_path):
    em = ErrorModel(
        disturbance=DisturbanceStats(max=0.01, source="inputs", n_steps=100),
        eps_e=0.05,
        eps_e_percentiles={"p95": 0.04},
        radius=1.0,
        s_slope=SlopeStats(max=11.7, percentiles={"p50": 0.13, "p95": 0.4}),
        R0=0.05,
        delta=0.05,
        n_samples=100,
        n_pairs=1000,
    )
    f = tmp_path / "fit" / "error_model.yaml"
    f.parent.mkdir()
    f.write_text(dump_yaml(em))
    return f


def _synth(*args):
    return RUN.invoke(app, ["synth", *map(str, args)])


def _reference_norms(folder):
    with np.load(folder / "controller.npz") as d:
        xy, xx, h = d["Phi_xy"], d["Phi_xx"], d["H"]
    # independent of sls.l1_norm: the largest absolute row sum over all taps side by side
    rows_xy = np.concatenate(list(xy), axis=1)
    rows_xx = np.concatenate([t @ h for t in xx], axis=1)
    return np.abs(rows_xy).sum(axis=1).max(), np.abs(rows_xx).sum(axis=1).max()


def test_paper_controllers_with_certificates(tmp_path, error_model):
    out = tmp_path / "synth"
    res = _synth("--model", error_model.parent, "-T", T, "--S", "p50", "--out", out)
    assert res.exit_code == 0, res.output
    names = ["pd", "l1_nominal", "l1_robust", "l1_robust_imitation"]
    assert sorted(p.name for p in out.iterdir() if p.is_dir()) == sorted(names)
    manifest = yaml.safe_load((out / "manifest.json").read_text())
    assert manifest["stage"] == "synth"
    sha = sha256_file(error_model)
    certs = {n: yaml.safe_load((out / n / "certificate.yaml").read_text()) for n in names}
    for n in names[1:]:
        c = certs[n]
        # the nominal ignores the constraint: verified, but no guarantee at this S; S = p50
        # leaves training pairs outside the premise: relaxed, never plainly certified
        want = "uncertified" if n == "l1_nominal" else "relaxed"
        assert c["status"] == want, (n, c["checks"])
        assert all(v["passed"] for k, v in c["checks"].items() if k != "robustness")
        assert c["error_model_sha256"] == sha
        assert c["achievability_residual"] <= 1e-7 and c["realization_error"] <= 1e-8
        # norms recomputed from the stored taps reproduce the certificate
        nxy, nxx = _reference_norms(out / n)
        assert nxy == pytest.approx(c["norm_phi_xy"], rel=1e-12)
        assert nxx == pytest.approx(c["norm_phi_xx_h"], rel=1e-12)
        lhs = (c["S"] + c["eps_e"] / c["radius"]) * nxy + (c["eps_w"] * nxx + c["delta"]) / c[
            "radius"
        ]
        assert lhs == pytest.approx(c["robustness_lhs"], rel=1e-12)
        assert (lhs < 1) == (want == "relaxed")
        # the premise, stated: p50 below the max (violated, share unknown without the
        # training states), eps_e = max (violated by none)
        p = c["premise"]
        assert (p["S"]["chosen"], p["S"]["value"], p["S"]["violated"]) == ("p50", 0.13, None)
        assert (p["eps_e"]["chosen"], p["eps_e"]["violated"]) == ("max", 0.0)
        assert (
            p["r"]["value"] == 1.0 and p["Delta"]["value"] == 0.05 and p["eps_w"]["value"] == 0.01
        )
        assert "no training_states.parquet" in p["training_data"]
        a = c["eps_w"] * nxx + c["delta"]
        assert c["gamma"] == pytest.approx(
            (c["eps_e"] + c["S"] * a) / (1 - c["S"] * nxy), rel=1e-12
        )
        assert c["gamma_strict"] == pytest.approx(c["R0"] / (1 - c["S"] * nxy), rel=1e-12)
        # R0 is the eps_e in use unless set, so the paper's stricter bound never exceeds gamma
        assert c["R0"] == c["eps_e"] and c["gamma_strict"] <= c["gamma"]
        for key in ("T", "eps_w", "margin", "cost", "controller_sha256"):
            assert key in c
        assert not {"build_time_s", "solve_time_s"} & set(c)  # timings: manifest only
        assert set(manifest["results"]["timings"][n]) == {"build_time_s", "solve_time_s"}
    assert certs["l1_nominal"]["robust"] is False and certs["l1_robust"]["robust"] is True
    assert certs["l1_robust"]["S"] == 0.13 and certs["l1_robust"]["eps_e"] == 0.05
    # S = 0.13 makes the constraint active: the nominal violates it, the robust one sits on it
    assert certs["l1_nominal"]["robustness_lhs"] > 1
    assert 0 < certs["l1_robust"]["margin"] < 1e-4
    assert certs["pd"]["status"] == "reference"


def test_realized_controllers_fly_the_impulse_responses(tmp_path, error_model):
    out = tmp_path / "synth"
    assert _synth("-m", error_model, "-T", T, "--S", "0.13", "-o", out).exit_code == 0
    m = quadrotor_model()
    for name in ("l1_robust", "l1_robust_imitation"):
        ctrl = load_controller(out / name)
        assert ctrl.dt == 0.1 and ctrl.strictly_proper is False
        assert ctrl.certificate["controller"] == name
        with np.load(out / name / "controller.npz") as d:
            xy, uy = d["Phi_xy"], d["Phi_uy"]
        # an error impulse e[0] = unit vector 3 (vx): x and u follow column 3 of Phi_xy, Phi_uy
        ctrl.reset()
        x = np.zeros(6)
        for k in range(2 * T):
            e = np.eye(6)[3] if k == 0 else np.zeros(6)
            u = ctrl.step(m.C @ x + e)
            want_x = xy[k][:, 3] if k <= T else np.zeros(6)
            want_u = uy[k][:, 3] if k <= T else np.zeros(3)
            np.testing.assert_allclose(x, want_x, atol=1e-9)
            np.testing.assert_allclose(u, want_u, atol=1e-9)
            x = m.A @ x + m.B @ u
    pd = load_controller(out / "pd")
    y = np.arange(6.0)
    np.testing.assert_allclose(pd.step(y), pd_gain(PDGains(), 0.256) @ y)


def test_strictly_proper_h2_single(tmp_path, error_model):
    out = tmp_path / "s"
    res = _synth(
        "-m", error_model, "-T", T, "--S", "0.1", "--norm", "h2", "--controllers", "single",
        "--strictly-proper", "-o", out,
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in out.iterdir() if p.is_dir()) == ["h2_robust", "pd"]
    ctrl = load_controller(out / "h2_robust")
    assert ctrl.strictly_proper and ctrl.certificate["status"] == "relaxed"
    with np.load(out / "h2_robust" / "controller.npz") as d:
        assert np.abs(d["Phi_uy"][0]).max() == 0


def test_controller_files_are_deterministic(tmp_path, error_model):
    for o in ("a", "b"):
        assert _synth("-m", error_model, "-T", 8, "--S", "0.1", "-o", tmp_path / o).exit_code == 0
    for n in ("pd", "l1_robust", "l1_robust_imitation"):
        assert sha256_file(tmp_path / "a" / n / "controller.npz") == sha256_file(
            tmp_path / "b" / n / "controller.npz"
        )


def test_infeasible_is_exit_3_with_diagnosis(tmp_path, error_model):
    out = tmp_path / "inf"
    res = _synth("-m", error_model, "-T", T, "--S", "max", "-o", out)  # S = max = 11.7
    assert res.exit_code == 3
    assert "necessary condition S + eps_e/r < 1" in res.output
    found = re.search(
        r"smallest achievable N = \|\|W_x Phi_xy W_e\^-1\|\| at T=12 is ([0-9.]+)", res.output
    )
    assert float(found.group(1)) == pytest.approx(
        largest_s.min_phi_xy(quadrotor_model(), 12), rel=1e-3
    )
    assert "largest feasible S for this setting is" in res.output
    _only_the_feasible_written(out, res.output)
    # the necessary condition holds but ||Phi_xy|| >= 2.x makes S = 0.45 infeasible
    res = _synth("-m", error_model, "-T", T, "--S", "0.45", "-o", tmp_path / "inf2")
    assert res.exit_code == 3 and "condition S + eps_e/r < 1 holds" in res.output
    _only_the_feasible_written(tmp_path / "inf2", res.output)
    # Delta / r >= 1: no S at all
    res = _synth(
        "-m", error_model, "-T", T, "--S", "0.01", "--delta", "1.2", "-o", tmp_path / "inf3"
    )  # fmt: skip
    assert res.exit_code == 3 and "no S >= 0 is feasible" in res.output, res.output
    _only_the_feasible_written(tmp_path / "inf3", res.output)


def _only_the_feasible_written(out, output):
    """An infeasible robust design still writes the controllers that are feasible (the PD
    and the nominal), each loadable, and names the infeasible ones in the manifest."""
    import json

    written = sorted(p.name for p in out.iterdir() if p.is_dir())
    assert written == ["l1_nominal", "pd"], written
    for n in written:
        assert load_controller(out / n) is not None
    results = json.loads((out / "manifest.json").read_text())["results"]
    assert sorted(results["infeasible"]) == ["l1_robust", "l1_robust_imitation"]
    assert set(results["controllers"]) == {"pd", "l1_nominal"}
    text = " ".join(output.split())
    assert "l1_robust, l1_robust_imitation: " in text and "pd, l1_nominal (feasible" in text


def test_max_feasible_s_is_feasible_and_one_percent_above_is_not(tmp_path, error_model):
    res = _synth("-m", error_model, "-T", T, "--max-feasible-s")
    assert res.exit_code == 0, res.output
    printed = float(re.search(r"largest feasible S\s*│\s*([0-9.e-]+)", res.output).group(1))
    s_max = max_feasible_s(error_model, SynthOptions(T=T)).s_max
    assert printed == pytest.approx(s_max, rel=1e-5)
    single = ["--controllers", "single", "-m", error_model, "-T", T]
    ok = _synth(*single, "--S", repr(s_max), "-o", tmp_path / "ok")
    assert ok.exit_code == 0, ok.output
    cert = yaml.safe_load((tmp_path / "ok" / "l1_robust" / "certificate.yaml").read_text())
    assert cert["status"] == "relaxed" and cert["margin"] > 0  # S < max
    bad = _synth(*single, "--S", repr(1.01 * s_max), "-o", tmp_path / "bad")
    assert bad.exit_code == 3 and not (tmp_path / "bad" / "l1_robust").exists()
    # the bound is tight: the certified controller at S_max has ||Phi_xy|| where the
    # constraint is active
    assert cert["margin"] < 1e-4


def test_max_feasible_s_when_no_s_is_feasible_says_why(error_model):
    """eps_e/r so large that even S = 0 is infeasible: the answer is words and exit 3, not -inf."""
    res = _synth("-m", error_model, "-T", T, "--eps-e", "0.6", "--max-feasible-s")
    assert res.exit_code == 3, res.output
    line = res.output.strip()
    assert "no S >= 0 is feasible" in line and "inf" not in line.replace("infeasible", "")
    assert len(line.splitlines()) == 1
    assert "none feasible: lower eps_e" in line  # the fix first (issue 50)
    lower = float(line.split("/ r < 1, at least ")[1].split(" with")[0])
    assert lower >= 1.0  # the stated reason: the S = 0 constraint's lower bound exceeds 1


def _bad_model_file(tmp_path, text):
    f = tmp_path / "bad.yaml"
    f.write_text(text)
    return f


@pytest.mark.parametrize(
    ("case", "pattern"),
    [
        ("missing", r"no error_model\.yaml"),
        ("not_yaml", r"not valid YAML"),
        ("malformed", r"malformed error model"),
        ("T1", r"'T'.*greater than or equal to 2"),
        ("Q", r"'Q'.*positive definite"),
        ("R", r"'R'.*positive definite"),
        ("name", r"'p77' is not in the error model"),
        ("eps_name", r"'p12' is not in the error model's eps_e_percentiles"),
    ],
)
def test_bad_input_is_one_clear_error(tmp_path, error_model, case, pattern):
    args = ["-m", error_model, "-T", T, "--S", "0.1"]
    if case == "missing":
        args[1] = tmp_path / "nowhere"
    elif case == "not_yaml":
        args[1] = _bad_model_file(tmp_path, "eps_e: [0.1\n")
    elif case == "malformed":
        args[1] = _bad_model_file(tmp_path, "eps_e: 0.1\nradius: fast\n")
    elif case == "T1":
        args[3] = 1
    elif case == "Q":
        args += ["--Q", "10,10,10,1,1,0"]
    elif case == "R":
        args += ["--R", "1,-1,0.1"]
    elif case == "name":
        args[5] = "p77"
    elif case == "eps_name":
        args += ["--eps-e", "p12"]
    out = tmp_path / "out"
    res = _synth(*args, "-o", out)
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.output.strip().splitlines() if ln]
    assert len(lines) == 1 and lines[0].startswith("error: "), res.output
    assert re.search(pattern, lines[0]), lines[0]
    assert "Traceback" not in res.output
    assert not out.exists()


def test_number_names_need_an_error_model(tmp_path):
    res = _synth("-T", T, "--S", "p95", "--eps-e", "0.05", "--radius", "1", "-o", tmp_path / "o")
    assert res.exit_code == 2 and "none was given" in res.output
    # all numbers: no error model needed
    res = _synth("-T", 6, "--S", "0.1", "--eps-e", "0.05", "--radius", "1", "-o", tmp_path / "o")
    assert res.exit_code == 0, res.output
    cert = yaml.safe_load((tmp_path / "o" / "l1_robust" / "certificate.yaml").read_text())
    # no error model: the numbers are the user's premise, no training data contradicts it
    assert cert["error_model_sha256"] is None and cert["status"] == "relaxed"
    assert cert["premise"]["training_data"] is None
    assert (
        sls.l1_norm(np.asarray(load_controller(tmp_path / "o" / "l1_robust").bank.K_by)[None]) > 0
    )


def test_shipped_config_is_valid():
    from pathlib import Path

    from qsls.pipeline.core.config import load_options

    cfg = Path(__file__).resolve().parents[1] / "configs" / "synth.yaml"
    opts = load_options(SynthOptions, cfg)
    assert opts.T == 20 and opts.norm == "l1" and opts.S == "lofo"


def test_s_at_least_one_says_no_radius_can_help(tmp_path, error_model):
    """S >= 1 breaks S N < 1 for every achievable response: the diagnosis says that no radius
    or horizon can help and what could (issue 26, item 11)."""
    res = _synth("-m", error_model, "-T", 8, "--S", "1.2", "-o", tmp_path / "o")
    assert res.exit_code == 3, res.output
    assert "no radius or horizon can help" in " ".join(res.output.split())
    assert not (tmp_path / "o" / "l1_robust").exists()


def test_certificates_do_not_depend_on_where_the_run_lives(tmp_path, error_model):
    """The certificate records the error model by its sha256, never by a path: the same
    synthesis from two folders writes byte-identical certificates (issue 26, item 4)."""
    import shutil

    outs = []
    for where in ("a/deep/folder", "b"):
        fit = tmp_path / where / "fit"
        shutil.copytree(error_model.parent, fit)
        out = tmp_path / where / "synth"
        res = _synth("-m", fit, "-T", 8, "--S", "0.05", "--controllers", "single", "-o", out)
        assert res.exit_code == 0, res.output
        outs.append((out / "l1_robust" / "certificate.yaml").read_bytes())
    assert outs[0] == outs[1]
    assert str(tmp_path).encode() not in outs[0]


def _training(n=400, seed=0):
    from qsls.pipeline.premise.measure import TrainingStates

    rng = np.random.default_rng(seed)
    x = rng.uniform(-1, 1, (n, 6))
    flight = (x[:, 0] > 0).astype(int)
    e = 0.01 * (1 + flight[:, None]) * np.sin(2 * x) + rng.normal(0, 0.002, x.shape)
    return TrainingStates(x, e, flight, rng.uniform(-0.01, 0.01, x.shape))


def _without_source(cert):
    """A certificate's YAML without where its shares were counted and its model file's hash."""
    premise = cert.premise.model_copy(update={"training_data": None})
    return cert.model_copy(update={"premise": premise, "error_model_sha256": None}).to_yaml()


def test_synthesize_in_memory_matches_the_stage_on_the_same_training_states(tmp_path):
    """The pure core and the stage are one computation: ``synthesize`` on training states in
    memory gives the certificate ``qsls synth`` writes from the same states saved beside the
    error model (the same bytes, but for where the shares were counted), and a sweep over T
    measures the premise once per measuring spec on the one training object."""
    import pandas as pd

    from qsls.pipeline.control.artifacts import Certificate
    from qsls.pipeline.control.sweep import SweepOptions, grid_points
    from qsls.pipeline.control.synth import synth, synthesize
    from qsls.pipeline.errormodel.model import W_COLS
    from qsls.pipeline.ingest.flight import E_COLS, X_COLS

    tr = _training()
    em = ErrorModel(eps_e=float(np.abs(tr.e).max()), radius=1.0, s_slope=SlopeStats(max=1.0),
                    R0=0.0, delta=0.05, n_samples=len(tr.x), n_pairs=0)  # fmt: skip
    opts = SynthOptions(T=8, S="lofo", eps_e="max", controllers="single")
    mem = synthesize(ModelInput(em, training=tr), opts).controllers["l1_robust"].certificate
    assert mem.status == "relaxed" and mem.premise is not None and mem.premise.holds
    assert mem.S > 0 and mem.premise.S.chosen == "lofo" and mem.premise.S.violated == 0.0
    fit = tmp_path / "fit"
    fit.mkdir()
    (fit / "error_model.yaml").write_text(dump_yaml(em))
    df = pd.DataFrame(np.hstack([tr.x, tr.e, tr.w]), columns=[*X_COLS, *E_COLS, *W_COLS])
    df.insert(0, "flight", np.where(tr.flight == 0, "a", "b"))
    df.to_parquet(fit / "training_states.parquet")
    synth(fit, opts, tmp_path / "out")
    disk = Certificate.load(tmp_path / "out" / "l1_robust")
    assert disk.premise is not None and disk.premise.training_data != mem.premise.training_data
    assert _without_source(disk) == _without_source(mem)
    tr2 = _training()
    sweep = SweepOptions(S="lofo", eps_e="max", grid={"T": [6, 8], "eps_w": [0.01, 0.02]})
    points = grid_points(sweep, em, tr2)
    assert len(points) == 4 and len(tr2._measured) == 2  # one per window T, not per point
