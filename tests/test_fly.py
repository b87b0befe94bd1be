"""Flying the controllers (qsls fly) through the real stages.

simulate -> ingest -> fit -> synth build the inputs; the realized controllers are checked
against their responses on the linear model by an independent simulation.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import yaml
from typer.testing import CliRunner

from qsls.cli.main import app
from qsls.pipeline.control.artifacts import load_runtime as load_controller
from qsls.pipeline.control.synth import SynthOptions, synth
from qsls.pipeline.core.plant import quadrotor_model
from qsls.pipeline.errormodel.fit import FitOptions, fit
from qsls.pipeline.fly.options import FlyOptions
from qsls.pipeline.fly.stage import fly_evaluate
from qsls.pipeline.ingest.stage import IngestOptions, ingest
from qsls.pipeline.sim.simulate import SimOptions, simulate

# A steep ridge across x = 0.35 m: slope 0.2 / 0.2 = 1 in e_px, so L >= 1. The training
# circle (centre (-1.2, 1.2), radius 0.4) stays where the field is flat; the default circle
# (radius 1 about the origin) crosses the ridge twice per lap.
STEEP_VIO = {
    "drift": False,
    "noise": False,
    "outliers": False,
    "blur": False,
    "motion_drift": False,
    "feature_loss": False,
    "ridges": [
        {"normal_deg": 0.0, "offset": 0.35, "width": 0.2, "amplitude": [0.2, 0, 0, 0, 0, 0]},
    ],
}
S_CERTIFIED = 0.05


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """Training flight (SE3, flat region) -> ingest -> fit -> synth (PD + L1 robust)."""
    root = tmp_path_factory.mktemp("fly")
    sim = SimOptions.model_validate(
        {
            "duration": 10.0,
            "seed": 0,
            "vio": STEEP_VIO,
            "reference": {"radius": 0.4, "center": [-1.2, 1.2], "period": 4.0},
        }
    )
    res = simulate(sim, root / "train_sim")
    ingest([res.bag], IngestOptions(), root / "train")
    fit([root / "train"], FitOptions(radius=2.0, figures=False), root / "fit")
    opts = SynthOptions(T=15, S=S_CERTIFIED, eps_e="max", delta=0.0, controllers="single")
    synth(root / "fit", opts, root / "synth")
    return root, float(res.truth["lipschitz"])


def _impulse_run(ctrl, model, w0=None, e0=None, steps=25):
    """The linear closed loop ``x+ = A x + B u + H w``, ``y = x + e``, ``u = K y``, driven by
    one impulse at k = 0; returns x[0..steps], u[0..steps-1]."""
    nx = model.A.shape[0]
    x = np.zeros(nx)
    xs, us = [x.copy()], []
    ctrl.reset()
    for k in range(steps):
        e = e0 if (k == 0 and e0 is not None) else np.zeros(nx)
        w = w0 if (k == 0 and w0 is not None) else np.zeros(nx)
        u = ctrl.step(model.C @ x + e)
        x = model.A @ x + model.B @ u + model.H @ w
        xs.append(x.copy())
        us.append(u.copy())
    return np.array(xs), np.array(us)


@pytest.mark.parametrize("strictly_proper", [False, True])
def test_realized_controller_reproduces_phi(tmp_path, strictly_proper):
    T = 12
    opts = SynthOptions(
        T=T, S=0.1, eps_e=0.05, radius=1.0, delta=0.0, R0=0.05,
        controllers="single", strictly_proper=strictly_proper,
    )  # fmt: skip
    synth(None, opts, tmp_path / "s")
    folder = tmp_path / "s" / "l1_robust"
    ctrl = load_controller(folder)
    with np.load(folder / "controller.npz") as z:
        phi = {k: z[k] for k in ("Phi_xx", "Phi_ux", "Phi_xy", "Phi_uy")}
    model = quadrotor_model()
    steps = T + 8
    for j in range(6):
        unit = np.eye(6)[j]
        # impulse in w: x[k] = Phi_xx(k) H e_j, u[k] = Phi_ux(k) H e_j, zero after T
        xs, us = _impulse_run(ctrl, model, w0=unit, steps=steps)
        for k in range(steps):
            want_x = phi["Phi_xx"][k] @ model.H @ unit if k <= T else np.zeros(6)
            want_u = phi["Phi_ux"][k] @ model.H @ unit if k <= T else np.zeros(3)
            np.testing.assert_allclose(xs[k], want_x, atol=1e-8)
            np.testing.assert_allclose(us[k], want_u, atol=1e-8)
        # impulse in e: x[k] = Phi_xy(k) e_j, u[k] = Phi_uy(k) e_j
        xs, us = _impulse_run(ctrl, model, e0=unit, steps=steps)
        for k in range(steps):
            want_x = phi["Phi_xy"][k] @ unit if k <= T else np.zeros(6)
            want_u = phi["Phi_uy"][k] @ unit if k <= T else np.zeros(3)
            np.testing.assert_allclose(xs[k], want_x, atol=1e-8)
            np.testing.assert_allclose(us[k], want_u, atol=1e-8)
    # strictly proper: u[0] does not see y[0]
    if strictly_proper:
        assert np.abs(phi["Phi_uy"][0]).max() == 0.0
        _, us = _impulse_run(ctrl, model, e0=np.ones(6), steps=2)
        assert np.abs(us[0]).max() == 0.0


def test_s_below_lipschitz_is_reported_as_assumption_violation(trained, tmp_path):
    root, lipschitz = trained
    assert lipschitz > 5 * S_CERTIFIED  # certified with an S well below the true constant
    cert = yaml.safe_load((root / "synth" / "l1_robust" / "certificate.yaml").read_text())
    assert cert["status"] in ("certified", "relaxed")  # on the training data's premise
    opts = FlyOptions(
        seeds=[0], duration=10.0, conditions=["regular"], controllers=["l1_robust"],
        se3=False, jobs=1, figures=False, sim=SimOptions.model_validate({"vio": STEEP_VIO}),
    )  # fmt: skip
    res = fly_evaluate(root / "fit", [root / "synth"], opts, tmp_path / "ev")
    row = res.table[res.table["controller"] == "l1_robust"].iloc[0]
    # The theorem is checked on its own flight; the bound fails where the ridge is crossed,
    # and the premise check says why: the error exceeds eps_e + S d there.
    assert row["theorem_applies"] and row["flown_by"] == "l1_robust"
    assert row["a_nominal"] > 0 and np.isfinite(row["gamma_nominal"])
    assert not row["bound_holds"] and row["max_error_norm"] > row["gamma_nominal"]
    assert row["verdict"].startswith("FAILS: max ||e||")
    assert not row["local_bound_holds"] and row["frac_under_gamma"] < 1.0
    assert row["max_ratio"] > 1.5
    assert not row["assumption_holds"] and row["max_premise_ratio"] > 1.5
    assert row["max_slope_to_training"] > S_CERTIFIED or np.isnan(row["max_slope_to_training"])
    assert "premise violated" in row["verdict"]
    # Where: on the default circle (radius 1), which the training states never visited.
    assert np.hypot(row["max_ratio_px"], row["max_ratio_py"]) == pytest.approx(1.0, abs=0.3)
    doc = json.loads((tmp_path / "ev" / "evaluation.json").read_text())
    assert any("3." in c["finding"] and c["agrees"] == "no" for c in doc["comparison"])
    # the held-out flight went through ingest like a real one
    flight = tmp_path / "ev" / "flights" / "regular_s0_l1_robust"
    assert json.loads((flight / "manifest.json").read_text())["stage"] == "ingest"


def test_fly_cli_flies_in_parallel_and_compares(trained, tmp_path):
    root, _ = trained
    cfg = tmp_path / "fly.yaml"
    cfg.write_text(
        yaml.safe_dump(
            {
                "fly": {"smooth_s": 0.5, "controllers": ["pd", "l1_robust"], "duration": 8.0},
            }
        )
    )
    out = tmp_path / "ev"
    args = ["fly", "--model", root / "fit", "--controller", root / "synth",
            "--out", out, "--config", cfg, "--seeds", "3", "--jobs", "2"]  # fmt: skip
    r = CliRunner().invoke(app, [str(a) for a in args])
    assert r.exit_code == 0, r.output
    flights = pd.read_parquet(out / "flights.parquet")
    assert len(flights) == 2 * 3  # (pd, l1_robust, se3) x (regular, degraded) x 1 seed
    assert set(flights["controller"]) == {"pd", "l1_robust", "se3"}
    assert not flights["crashed"].any()
    assert (flights["tracking_rms_m"] < 0.3).all()
    # degraded perception is worse than regular, for every controller
    piv = flights.pivot(index="controller", columns="condition", values="perception_error_rms")
    assert (piv["degraded"] > piv["regular"]).all()
    doc = json.loads((out / "evaluation.json").read_text())
    assert [c["finding"][:2] for c in doc["comparison"]] == ["1.", "2.", "3.", "4."]
    # PD on its own estimate is exactly itself: its softness ratio is 1
    pd_rows = flights[flights["controller"] == "pd"]
    np.testing.assert_allclose(pd_rows["smoothness_vs_pd"], 1.0, rtol=1e-9)
    np.testing.assert_allclose(pd_rows["attitude_diff_from_pd_rms"], 0.0, atol=1e-12)
    ev = pd.read_parquet(out / "evaluation.parquet")
    assert {"flown_by", "gamma", "gamma_strict", "max_ratio", "max_distance_to_training"} <= set(
        ev.columns
    )
    for name in ("tracking_regular.png", "tracking_degraded.png", "perception_error.png",
                 "input_l1_robust_vs_pd.png", "distance_to_training.png"):  # fmt: skip
        assert (out / name).stat().st_size > 1000, name
    assert "Against the paper" in r.output
    md = (out / "comparison.md").read_text()
    assert sum(md.count(f"\n| {i}. ") for i in (1, 2, 3)) == 3
    # 'evaluate --fly', the old spelling, is gone: a one-line pointer to 'qsls fly' (with or
    # without the other options), nothing written
    old = ["evaluate", "--fly", *args[1:-4], "--flights", root / "train", "--out", tmp_path / "x"]
    fly_args = ["--seeds", "0", "--conditions", "regular", "--jobs", "2"]  # qsls fly's own
    for argv in (old, ["evaluate", "--fly"], ["evaluate", "--fly", *fly_args]):
        r = CliRunner().invoke(app, [str(a) for a in argv])
        assert r.exit_code == 2 and r.output.strip().splitlines() == [
            "error: 'qsls evaluate --fly' is now 'qsls fly' (the same options)"
        ], r.output
    assert not (tmp_path / "x").exists()


def test_crash_ends_flight_safely_and_is_flagged(trained, tmp_path):
    root, _ = trained
    sim = SimOptions.model_validate({"crash": {"max_deviation": 0.01}})
    opts = FlyOptions(
        seeds=[1], duration=6.0, conditions=["degraded"], controllers=["l1_robust"],
        se3=False, jobs=1, sim=sim,
    )  # fmt: skip
    res = fly_evaluate(root / "fit", [root / "synth"], opts, tmp_path / "ev")
    row = res.flights.iloc[0]
    assert row["crashed"] and "diverged" in row["crash_reason"]
    assert row["duration_s"] < 6.0
    assert any("crashed, flight ended safely" in w for w in res.warnings)
    doc = json.loads((tmp_path / "ev" / "evaluation.json").read_text())
    assert doc["flights_table"][0]["crashed"] is True


def test_model_hash_mismatch_with_real_stages(trained, tmp_path):
    root, _ = trained
    fit([root / "train"], FitOptions(radius=1.5, figures=False), tmp_path / "fit2")
    args = ["evaluate", "--model", tmp_path / "fit2", "--controller", root / "synth" / "l1_robust",
            "--flights", root / "train", "--out", tmp_path / "ev"]  # fmt: skip
    r = CliRunner().invoke(app, [str(a) for a in args])
    assert r.exit_code == 2 and "designed against error model" in r.output  # relaxed: not certified
    assert not (tmp_path / "ev").exists()
    r = CliRunner().invoke(app, [str(a) for a in [*args, "--force", "--no-figures"]])
    assert r.exit_code == 0 and "warning:" in r.output
    # the training flight itself: distance 0 to the training states, the bound holds there
    ev = pd.read_parquet(tmp_path / "ev" / "evaluation.parquet")
    assert ev["max_distance_to_training"].iloc[0] == pytest.approx(0.0, abs=1e-12)


def test_pd_height_channel_option(trained, tmp_path):
    """pd_z_control (the paper's setup): thrust from PD on the same estimate, attitude not."""
    from qsls.pipeline.fly.flights import FlyJob, run_job

    root, _ = trained
    sim = SimOptions().model_dump(mode="json")
    sim["duration"] = 4.0
    job = FlyJob(
        "z", "l1_robust", str(root / "synth" / "l1_robust"), "regular", 0, sim,
        IngestOptions().model_dump(mode="json"), str(tmp_path / "sim"), str(tmp_path / "fl"),
        pd_z=True,
    )  # fmt: skip
    o = run_job(job)
    np.testing.assert_allclose(o.u_ctrl[:, 2], o.u_pd[:, 2], rtol=1e-12)
    assert np.abs(o.u_ctrl[:, :2] - o.u_pd[:, :2]).max() > 1e-3


def test_assured_flights_are_kept_apart(trained, tmp_path):
    """``assured: true`` adds the monitored controller's runtime-assured flight (its tick log
    says who flew each tick, ``assured.parquet`` its handover) and leaves every other table
    byte-identical to the stage without it."""
    root, _ = trained
    kw = dict(seeds=[0], duration=3.0, conditions=["regular"], controllers=["l1_robust"],
              se3=False, jobs=1, figures=False)  # fmt: skip
    plain = fly_evaluate(root / "fit", [root / "synth"], FlyOptions(**kw), tmp_path / "plain")
    res = fly_evaluate(
        root / "fit", [root / "synth"], FlyOptions(**kw, assured=True), tmp_path / "assured"
    )
    for name in ("flights.parquet", "assumptions.parquet", "per_controller.parquet"):
        assert (tmp_path / "plain" / name).read_bytes() == (
            tmp_path / "assured" / name
        ).read_bytes()
    assert len(plain.flights) == len(res.flights) == 1
    a = pd.read_parquet(tmp_path / "assured" / "assured.parquet")
    assert a["flight"].tolist() == ["regular_s0_l1_robust_assured"]
    assert a["controller"].tolist() == ["l1_robust"] and a["fallback"].tolist() == ["pd"]
    ticks = pd.read_parquet(tmp_path / "assured" / "flights" / a["flight"][0] / "ticks.parquet")
    alone = pd.read_parquet(
        tmp_path / "assured" / "flights" / "regular_s0_l1_robust" / "ticks.parquet"
    )
    # no trip: the certified controller's own flight, tick for tick
    assert not a["tripped"][0] and a["trip_tick"][0] == -1 and 0 < a["envelope_peak"][0] < 1
    assert set(ticks["flew"]) == {"l1_robust"} and not ticks["monitor_bits"].any()
    pd.testing.assert_frame_equal(ticks[alone.columns], alone)
    assert not (tmp_path / "plain" / "assured.parquet").exists()


def test_assured_flights_per_estimator(trained, tmp_path):
    """Two estimators (camera, emulator): ``assured.parquet`` holds each estimator's assured
    flight, keyed by it; the comparison pairs each with its own estimator's flight (no trip in
    3 s: the same tracking, which differs between the estimators); the report's section
    shows a row per estimator."""
    from qsls.pipeline.report.facts import Facts
    from qsls.pipeline.report.monitor import section_monitor

    root, _ = trained
    opts = FlyOptions.model_validate(
        {"vio": ["camera", "emulator"], "seeds": [0], "duration": 3.0, "conditions": ["regular"],
         "controllers": ["l1_robust"], "se3": False, "jobs": 1, "figures": False,
         "assured": True}
    )  # fmt: skip
    fly_evaluate(root / "fit", [root / "synth"], opts, tmp_path / "fly")
    a = pd.read_parquet(tmp_path / "fly" / "assured.parquet")
    assert a["estimator"].tolist() == ["camera", "emulator"] and not a["tripped"].any()
    every = pd.read_parquet(tmp_path / "fly" / "flights_by_estimator.parquet")
    own = every.set_index("estimator")["tracking_rms_m"]
    np.testing.assert_array_equal(a["tracking_rms_m"], own[["camera", "emulator"]])
    assert own["camera"] != own["emulator"]
    comp = pd.DataFrame(json.loads((tmp_path / "fly" / "evaluation.json").read_text())["assured"])
    assert comp[["estimator", "flown"]].values.tolist() == [
        ["camera", "alone"],
        ["camera", "assured"],
        ["emulator", "alone"],
        ["emulator", "assured"],
    ]
    np.testing.assert_array_equal(comp["tracking_rms_m"], own[[v for v in comp["estimator"]]])
    sec = section_monitor(Facts(tmp_path, {}, {}, fly_folder="fly"), [0])
    rows = [b for kind, b in sec.blocks if kind == "table"][-1].rows
    assert [r[0] for r in rows] == ["regular (camera)"] * 2 + ["regular (emulator)"] * 2
