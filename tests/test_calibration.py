"""The calibrated premise (docs/calibration.md): the order statistics against hand computations,
the stated alpha met by exchangeable flights in repeated draws, the inflated condition on real
taps, the seed rule, and the tick log reproducing the scores."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.stats import binom

from qsls.pipeline.calibrate.core import set_by
from qsls.pipeline.calibrate.options import CalibrateOptions
from qsls.pipeline.control import calibration as cal
from qsls.pipeline.control import conformal
from qsls.pipeline.core.errors import ConfigError
from qsls.pipeline.evaluate.conditions import outside_conditions
from qsls.pipeline.premise.numbers import PremiseNumbers

QUICKSTART_CAL = yaml.safe_load(
    (Path(__file__).resolve().parents[1] / "configs" / "quickstart.yaml").read_text()
)["calibrate"]
CAL_SEED = int(QUICKSTART_CAL["seed"])
"""The quickstart's first calibration seed (its range and validation seeds beside it)."""


def test_conformal_rank_is_the_hand_computed_order_statistic() -> None:
    # ceil((n + 1)(1 - alpha)): n = 19, alpha 0.05 -> 19 (the maximum); n = 20, alpha 0.1 ->
    # ceil(18.9) = 19; n = 9, alpha 0.1 -> ceil(9.0) = 9; n = 8, alpha 0.1 -> ceil(8.1) = 9 > 8
    assert conformal.conformal_rank(19, 0.05) == 19
    assert conformal.conformal_rank(20, 0.1) == 19
    assert conformal.conformal_rank(9, 0.1) == 9
    assert conformal.conformal_rank(8, 0.1) == 9
    scores = [5.0, 1.0, 4.0, 2.0, 3.0, 9.0, 8.0, 7.0, 6.0, 10.0] * 2  # 20 flights
    # sorted: 1,1,2,2,...,10,10; rank 19 -> 10
    assert conformal.calibrated_quantile(scores, 0.1, "conformal") == 10.0
    assert conformal.calibrated_quantile(scores, 0.2, "conformal") == 9.0  # ceil(16.8) = 17 -> 9
    assert math.isinf(conformal.calibrated_quantile(scores[:8], 0.1, "conformal"))


def test_pac_rank_is_the_hand_computed_order_statistic() -> None:
    # the maximum of n flights (j = 1) needs (1 - alpha)^n <= delta: 29 flights for 90/95
    # ((0.9)^29 = 0.047), 28 are not enough ((0.9)^28 = 0.052)
    assert conformal.pac_rank(29, 0.1, 0.05) == 29
    assert conformal.pac_rank(28, 0.1, 0.05) == 29  # n + 1: not enough
    assert conformal.smallest_flights(0.1, "pac", 0.05) == 29
    assert conformal.smallest_flights(0.05, "pac", 0.05) == 59
    assert conformal.smallest_flights(0.05, "conformal") == 19
    # n = 100, alpha 0.1, delta 0.05: the largest j with P[Bin(100, .1) <= j - 1] <= .05
    j = max(j for j in range(1, 101) if binom.cdf(j - 1, 100, 0.1) <= 0.05)
    assert j == 5  # P[Bin <= 4] = 0.024, P[Bin <= 5] = 0.058
    assert conformal.pac_rank(100, 0.1, 0.05) == 100 - j + 1
    # the quantile itself: the 5th largest of 100 shuffled scores 0.01 .. 1.00 is 0.96
    scores = np.random.default_rng(1).permutation(np.arange(1, 101) / 100)
    assert conformal.calibrated_quantile(scores, 0.1, "pac", 0.05) == pytest.approx(0.96)
    assert conformal.calibrated_quantile(scores[:29], 0.1, "pac", 0.05) == scores[:29].max()
    assert conformal.calibrated_quantile(scores[:28], 0.1, "pac", 0.05) == math.inf


@pytest.mark.parametrize("method,alpha", [("conformal", 0.1), ("pac", 0.1)])
def test_stated_alpha_is_met_by_exchangeable_flights(
    method: conformal.Method, alpha: float
) -> None:
    """1000 draws of 29 calibration flights and one new flight from a heavy-tailed family: the
    new flight exceeds lambda_hat at a rate within the binomial interval of alpha (conformal:
    marginal, so the rate is at most alpha; PAC: each draw's own coverage is at least
    1 - alpha in at least 1 - delta of the draws)."""
    rng = np.random.default_rng(7)
    n, draws = 29, 1000
    dist = lambda size: np.exp(rng.standard_t(3, size=size))  # noqa: E731
    misses = 0
    bad_draws = 0
    for _ in range(draws):
        lam = conformal.calibrated_quantile(dist(n), alpha, method)
        misses += bool(dist(1)[0] > lam)
        if method == "pac":
            coverage = float(np.mean(dist(2000) <= lam))
            bad_draws += coverage < 1 - alpha
    lo, hi = binom.ppf([0.0005, 0.9995], draws, alpha) / draws
    rate = misses / draws
    assert rate <= hi, (rate, hi)
    if method == "conformal":
        # exact for continuous scores: 1 - ceil(30 * 0.9) / 30 = 0.1
        assert rate >= lo
    else:
        assert bad_draws / draws <= 0.05 + 3 * math.sqrt(0.05 * 0.95 / draws)


def test_a_family_that_breaks_exchangeability_is_caught_by_the_same_check() -> None:
    """The check above can fail: new flights drawn wider than the calibration flights exceed
    lambda_hat far more often than alpha."""
    rng = np.random.default_rng(3)
    misses = sum(
        bool(
            rng.normal(0, 2.0)
            > conformal.calibrated_quantile(rng.normal(0, 1, 29), 0.1, "conformal")
        )
        for _ in range(1000)
    )
    assert misses / 1000 > 0.2


def _taps() -> cal.Responses:
    from qsls.pipeline.control.guarantee import Norms

    rng = np.random.default_rng(0)
    phi_xy = rng.uniform(-0.05, 0.05, (11, 6, 6))
    phi_xx_h = rng.uniform(-0.05, 0.05, (11, 6, 6))
    from qsls.pipeline.control.sls import l1_norm

    return cal.Responses(phi_xy, phi_xx_h, (1.0,) * 6, (1.0,) * 6, tuple(range(6)), (3, 4, 5),
                    Norms(N=l1_norm(phi_xy), N_w=l1_norm(phi_xx_h), G_m=0.0))  # fmt: skip


def test_inflated_condition_and_tolerances_against_direct_arithmetic() -> None:
    taps = _taps()
    p = PremiseNumbers(eps=0.1, S=0.2, radius=1.0, eps_w=0.05, delta=0.1, eps_o=0.5, m=2)
    c = cal.check(p, taps)
    N, Nw = taps.norms.N, taps.norms.N_w
    per_tap = np.abs(taps.phi_xy[:, :, [3, 4, 5]]).sum(axis=2)
    gm = float(np.sort(per_tap, axis=0)[::-1][:2].sum(axis=0).max())
    lhs = (0.2 + 0.1) * N + (0.05 * Nw + 0.1 + 0.5 * gm) / 1.0
    assert c.G_m == pytest.approx(gm)
    assert c.guarantee.robustness_lhs == pytest.approx(lhs)
    assert c.holds == (lhs <= 1)
    lam = 1.7
    q = cal.inflate(p, lam)
    assert (q.eps, q.S, q.eps_w, q.delta, q.m) == pytest.approx((0.17, 0.34, 0.085, 0.17, 3))
    # tolerance of eps_w: lhs is linear in it, so the factor is 1 + slack / (eps_w N_w), and
    # rho* <= r is the same condition here (rho* <= r <=> lhs <= 1 when S N < 1)
    tol = cal.tolerance(p, taps, "eps_w")
    assert tol == pytest.approx(1 + (1 - lhs) / (0.05 * Nw), rel=1e-5)
    grown = cal.check(PremiseNumbers(**{**p.__dict__, "eps_w": 0.05 * tol * 1.001}), taps)
    assert not grown.holds
    # a quantity stated as 0 has an infinite factor; its largest value is the slack over its
    # coefficient: S enters lhs as S N, so S_max = (1 - lhs(S = 0)) / N
    p0 = PremiseNumbers(**{**p.__dict__, "S": 0.0})
    lhs0 = 0.1 * N + (0.05 * Nw + 0.1 + 0.5 * gm) / 1.0
    assert cal.tolerance(p0, taps, "S") == math.inf
    assert cal.largest_value(p0, taps, "S") == pytest.approx((1 - lhs0) / N, rel=1e-5)
    assert cal.largest_value(p, taps, "eps_w") == pytest.approx(0.05 * tol)


def test_a_flight_outside_the_calibrations_conditions_says_why() -> None:
    """The promise is about a new flight of the same conditions: another perception condition
    or a longer flight lies outside it; the verdict counts such flights."""
    import pandas as pd

    from qsls.pipeline.evaluate.verdict import assumption_verdicts

    assert outside_conditions("regular", 15.0, "regular", 15.0) == ""
    assert outside_conditions("regular", 12.0, "regular", 15.0) == ""  # shorter (a crash)
    assert outside_conditions("degraded", 15.0, "regular", 15.0) == (
        "perception degraded, calibrated in regular"
    )
    assert outside_conditions("regular", 30.0, "regular", 15.0) == (
        "a 30 s flight, calibrated on 15 s flights"
    )
    # another estimator: the camera loop and the emulator err their own ways ('' = not known)
    assert outside_conditions("regular", 15.0, "regular", 15.0, "emulator", "camera") == (
        "estimator emulator, calibrated with camera"
    )
    assert outside_conditions("regular", 15.0, "regular", 15.0, "camera", "camera") == ""
    assert outside_conditions("regular", 15.0, "regular", 15.0, "", "camera") == ""
    assert outside_conditions("regular", 15.0, "regular", 15.0, "emulator", "") == ""
    both = outside_conditions("degraded", 23.0, "regular", 15.0)
    assert (
        both
        == "perception degraded, calibrated in regular; a 23 s flight, calibrated on 15 s flights"
    )
    table = pd.DataFrame({
        "controller": ["c"] * 3, "flight": ["a", "b", "d"], "assumptions_hold": [True, False, False],
        "first_failed": ["", "dense", "dense"], "verdict": ["", "x", "y"],
        "bound_held": [True, True, True], "outside_calibration": ["", both, ""],
    })  # fmt: skip
    (v,) = assumption_verdicts(table)
    assert (v.outside, v.outside_why, v.outside_failing) == (1, both, 1)
    assert v.line().endswith(
        f"; also failing: d; 1 of the 3 flown outside its calibration ({both}), 1 of the 2 "
        "failing among them; inside it 1 of 2 failed"
    )
    assert "outside" not in assumption_verdicts(table.drop(columns="outside_calibration"))[0].line()
    # every flight outside: no count of the flights inside
    (away,) = assumption_verdicts(table.assign(outside_calibration=both))
    assert away.line().endswith(
        f"; 3 of the 3 flown outside its calibration ({both}), 2 of the 2 failing among them"
    )


def test_a_heldout_verdict_counts_rows_under_a_relaxed_conditions_certificate() -> None:
    """Per-condition certificates mix statuses in one controller's rows: the held-out verdict
    says how many were checked under the relaxed one, and takes the other's status."""
    import pandas as pd

    from qsls.pipeline.evaluate.verdict import verdicts

    table = pd.DataFrame({
        "controller": ["c", "c"], "flight": ["a", "b"], "status": ["relaxed", "certified"],
        "has_guarantee": [True, True], "theorem_applies": [False, False],
        "frac_premise_holds": [1.0, 1.0], "premise_holds": [True, True],
    })  # fmt: skip
    (v,) = verdicts(table)
    assert v.status == "certified" and v.relaxed == 1
    assert "2 flights (1 of them under a relaxed certificate: no guarantee there)" in v.line()
    assert "of a relaxed certificate," not in v.line()


def test_a_verdict_says_which_flights_were_checked_under_a_relaxed_premise() -> None:
    """A relaxed certificate promises nothing: the verdict on its flights says so, for every
    flight or (one condition certified, another relaxed) for those it concerns."""
    import pandas as pd

    from qsls.pipeline.evaluate.verdict import assumption_verdicts

    table = pd.DataFrame({
        "controller": ["c"] * 4, "flight": ["a", "b", "d", "e"],
        "assumptions_hold": [True, False, False, True], "first_failed": ["", "dense", "w", ""],
        "verdict": ["", "x", "y", ""], "bound_held": [True] * 4,
        "status": ["certified", "relaxed", "relaxed", "certified"],
    })  # fmt: skip
    (v,) = assumption_verdicts(table)
    assert v.relaxed == 2
    assert "FAILS on 2 of 4 flights (2 of them under a relaxed premise: no guarantee " in v.line()
    (v,) = assumption_verdicts(table.assign(status="relaxed"))
    assert "of 4 flights (relaxed premise: no guarantee claimed)" in v.line()
    (v,) = assumption_verdicts(table.assign(status="certified"))
    assert "relaxed" not in v.line()


def test_calibration_seeds_shared_with_design_flights_are_refused() -> None:
    opts = CalibrateOptions(flights=20, seed=1000, validation=20, validation_seed=2000,
                            design_seeds=[1, 2, 1005])  # fmt: skip
    with pytest.raises(ConfigError, match=r"calibration seeds \[1005\] are design flights"):
        opts.seed_lists()
    opts = CalibrateOptions(flights=20, seed=1000, validation=5, validation_seed=1010)
    with pytest.raises(
        ConfigError, match=r"validation seeds .* are also calibration or range seeds"
    ):
        opts.seed_lists()
    calib, valid = CalibrateOptions(design_seeds=[0, 1, 2]).seed_lists()
    assert calib == list(range(1000, 1020)) and valid == list(range(2000, 2020))


def test_run_refuses_a_calibration_that_shares_a_design_seed(tmp_path: Path) -> None:
    import subprocess
    import sys

    cfg = tmp_path / "c.yaml"
    cfg.write_text(
        "name: c\nflights:\n  - {name: a, simulate: {seed: 1001}}\n"
        "synth: {T: 10}\ncalibrate: {flights: 19, seed: 1000}\n"
    )
    r = subprocess.run([sys.executable, "-m", "qsls.cli.main", "run", str(cfg), "--out",
                        str(tmp_path / "out")], capture_output=True, text=True)  # fmt: skip
    assert r.returncode != 0
    assert "calibration seeds [1001] are design flights' seeds" in r.stderr
    assert "Traceback" not in r.stderr
    assert not (tmp_path / "out" / "simulate").exists()


def test_one_flight_twice_is_refused_and_the_model_records_its_dt(tmp_path: Path) -> None:
    """A flight counts once (issue 32): the same folder twice, a symlink to it, or one flight
    ingested with a second estimator (the same ground truth) is refused as separate folds; the
    error model records its dt and synth refuses a controller of another dt."""
    import shutil

    from qsls.pipeline.control.synth import SynthOptions, synth
    from qsls.pipeline.core.errors import InputError
    from qsls.pipeline.errormodel.fit import FitOptions, fit
    from qsls.pipeline.errormodel.model import load_error_model
    from qsls.pipeline.sim.vio import VioEmulator, VioParams
    from tests.test_fit import MOTION_OFF, circle_states, write_flight

    folders = []  # 40 s circle flights (a motion twin is recognized over 30 s or more)
    for seed in (0, 1):
        t, x = circle_states(seed, laps=8.0)
        e = VioEmulator(VioParams(**MOTION_OFF), seed).errors(x)
        folders.append(write_flight(tmp_path / "f" / f"flight{seed}", t, x, x + e))
    opts = FitOptions(radius=1.0)
    (tmp_path / "link").symlink_to(folders[0])
    twin = tmp_path / "twin"  # the first flight's truth with another estimate: one flight
    from qsls.pipeline.ingest.flight import Flight

    fl = Flight.load(folders[0]).frame
    from qsls.pipeline.evaluate.training import states

    x = states(fl)
    write_flight(twin, fl["t"].to_numpy(float), x, x + 0.01)
    # the same flight's truth from another export: 2 mm apart, in another frame (rotated and
    # moved), on stamps 0.05 s shifted
    rng = np.random.default_rng(1)
    c, s_ = np.cos(0.4), np.sin(0.4)
    rot = np.array([[c, -s_, 0], [s_, c, 0], [0, 0, 1]])
    xs = x + rng.normal(0, 0.002, x.shape)
    xs[:, :3] = xs[:, :3] @ rot.T + [0.5, -0.2, 0.1]
    xs[:, 3:] = xs[:, 3:] @ rot.T
    from qsls.pipeline.ingest.flight import make_flight_frame

    stamps = np.round((fl["t"].to_numpy(float) + 0.05) * 1e9).astype(np.int64)
    from qsls.pipeline.core.artifacts import StageWriter

    with StageWriter(tmp_path / "reexport", "ingest") as w:
        w.write_parquet("flight.parquet", make_flight_frame(stamps, xs, xs + 0.02))
    for second, how in ((folders[0], "the same folder"), (tmp_path / "link", "the same folder"),
                        (twin, "the same ground truth"),
                        (tmp_path / "reexport", "the same motion at the same times")):  # fmt: skip
        with pytest.raises(InputError, match=rf"are one flight \({how}\)"):
            fit([folders[0], folders[1], second], opts, tmp_path / "fit_bad", force=True)
    fit(folders, opts, tmp_path / "fit")
    model = load_error_model(tmp_path / "fit" / "error_model.yaml")
    assert model.dt == pytest.approx(0.1)
    with pytest.raises(
        InputError, match=r"dt 0.05 s: the error model was fitted on flights sampled every 0.1 s"
    ):
        synth(tmp_path / "fit", SynthOptions(T=8, dt=0.05, controllers="single"), tmp_path / "s")
    shutil.rmtree(tmp_path / "fit")


def test_calibration_on_a_dask_cluster_writes_the_local_pools_bytes_and_survives_a_lost_worker(
    quickstart_session, tmp_path: Path
) -> None:
    """Issue 37: the calibration and validation flights on a real `dask scheduler` with two
    `dask worker` processes on loopback, one killed while it flies; the scores, validation,
    tick logs and calibrated certificates are byte-identical to the local pool's."""
    import shutil
    import subprocess
    import sys
    import time

    from distributed import Client

    from tests.test_sweep import _Cluster, _wait_for_workers

    run = quickstart_session[0] / "runs" / "quickstart"
    for stage in ("fit", "synth"):
        shutil.copytree(run / stage, tmp_path / stage)
    args = [
        sys.executable, "-m", "qsls.cli.main", "calibrate", "-m", str(tmp_path / "fit"),
        "--controllers", str(tmp_path / "synth"), "--only", "l1_robust", "--flights", "4",
        "--range-flights", "2", "--tube", "2", "--validation", "2", "--duration", "4",
        "--seed", "91000", "--range-seed", "93000", "--validation-seed", "92000",
    ]  # fmt: skip
    local = subprocess.run([*args, "-o", str(tmp_path / "local"), "--jobs", "2"],
                           capture_output=True, text=True)  # fmt: skip
    assert local.returncode == 0, local.stderr[-2000:]
    cluster = _Cluster(tmp_path)
    try:
        doomed = cluster.worker()
        cluster.worker()
        _wait_for_workers(cluster.address, 2)
        proc = subprocess.Popen([*args, "-o", str(tmp_path / "dask"), "--scheduler", cluster.address],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
        with Client(cluster.address, timeout="20s", set_as_default=False) as client:
            deadline = time.monotonic() + 120
            while not any(client.processing().values()):
                assert proc.poll() is None and time.monotonic() < deadline
                time.sleep(0.05)
        doomed.kill()  # a worker lost while it flies: its flight goes to the other one
        _, err = proc.communicate(timeout=300)
    finally:
        cluster.stop()
    assert proc.returncode == 0, err[-2000:]
    files = sorted(
        p.relative_to(tmp_path / "local")
        for p in (tmp_path / "local").rglob("*")
        if p.is_file() and p.name != "manifest.json"
    )
    assert len([f for f in files if f.name == "ticks.parquet"]) == 8
    for f in files:
        assert (tmp_path / "dask" / f).read_bytes() == (tmp_path / "local" / f).read_bytes(), f


@pytest.mark.parametrize(
    ("edit", "why"),
    [
        ({"calibration": None, "premise": None}, "no calibration: only flights the design never"),
        ({"flights": 5, "scores": [0.5] * 5}, "5 calibration flights with 5 scores (needs 19)"),
        ({"alpha": 0.3}, "alpha 0.3 > 0.1"),
        ({"lambda_hat": 0.5}, "lambda_hat 0.5 below its scores' quantile"),
        ({"holds": False}, "the condition fails under the calibrated premise"),
        ({"tested_range": 0.2}, "tested to 0.2 < rho*"),
        ({"design_seeds": [CAL_SEED]}, f"calibration seeds [{CAL_SEED}] are design flights' seeds"),
        ({"eps_e": 0.0135}, "eps_e 0.0135 is not the design's"),
    ],
)
def test_a_certified_status_its_calibration_does_not_back_is_refused_on_read(
    quickstart_session, tmp_path: Path, edit: dict, why: str
) -> None:
    """The quickstart's certified `l1_robust` with one field of its record edited: every
    command that reads it (export; evaluate once) refuses it in one line, exit 2."""
    import shutil
    import subprocess
    import sys

    from qsls.pipeline.control.artifacts import Certificate

    run = quickstart_session[0] / "runs" / "quickstart"
    folder = tmp_path / "l1_robust"
    shutil.copytree(run / "calibrate" / "regular" / "l1_robust", folder)
    cert = Certificate.load(folder)
    assert cert.status == "certified" and cert.calibration is not None
    if {"tested_range", "calibration", "eps_e"} & set(edit):  # the certificate's own fields
        cert = cert.model_copy(update=edit)
    else:
        cert = cert.model_copy(update={"calibration": cert.calibration.model_copy(update=edit)})
    cert.save(folder)
    commands = [["export", str(folder), "--target", "c", "--out", str(tmp_path / "c")]]
    if "alpha" in edit:  # one case through a second reader is enough: both load it alike
        commands.append(["evaluate", "--model", str(run / "fit"), "--controller", str(folder),
                         "--flights", str(run / "ingest" / "heldout_1"),
                         "--out", str(tmp_path / "ev")])  # fmt: skip
    for args in commands:
        proc = subprocess.run([sys.executable, "-m", "qsls.cli.main", *args],
                              capture_output=True, text=True)  # fmt: skip
        out = proc.stdout + proc.stderr
        assert proc.returncode == 2, out[-2000:]
        assert len(out.strip().splitlines()) == 1 and why in out, out
        assert "says 'certified' against its own record" in out
    assert not (tmp_path / "c").exists() and not (tmp_path / "ev").exists()


def test_standalone_calibrate_reads_the_design_seeds_from_the_fit(
    quickstart_session, tmp_path: Path
) -> None:
    """Without --design-seeds, `qsls calibrate` finds the seeds of the flights the error model
    was fitted on (the fit's inputs back to their simulate manifests: the quickstart's 1, 2,
    4, 5) and refuses calibration seeds among them; the certificate records them."""
    import subprocess
    import sys

    from qsls.pipeline.calibrate.stage import fitted_seeds
    from qsls.pipeline.control.artifacts import Certificate

    run = quickstart_session[0] / "runs" / "quickstart"
    assert fitted_seeds(run / "fit") == [1, 2, 4, 5]
    proc = subprocess.run(
        [sys.executable, "-m", "qsls.cli.main", "calibrate", "-m", str(run / "fit"),
         "--controllers", str(run / "synth"), "--only", "l1_robust", "--seed", "1",
         "--flights", "2", "--validation", "0", "-o", str(tmp_path / "cal")],
        capture_output=True, text=True,
    )  # fmt: skip
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "calibration seeds [1, 2] are design flights' seeds" in proc.stdout + proc.stderr
    assert not (tmp_path / "cal").exists()
    cal_record = Certificate.load(run / "calibrate" / "regular" / "l1_robust").calibration
    assert cal_record is not None and cal_record.design_seeds == [1, 2, 4, 5]


def test_a_calibrated_certificate_reads_its_checks_under_the_calibrated_premise(
    quickstart_session,
) -> None:
    """The calibrated certificate's robustness and gate checks are the calibrated condition's
    (as its status is), the design's kept beside; the paper's comparison gamma_strict reads
    the calibrated error bound as its R0."""
    import yaml

    run = quickstart_session[0] / "runs" / "quickstart"
    cert = yaml.safe_load((run / "calibrate/regular/l1_robust/certificate.yaml").read_text())
    design = yaml.safe_load((run / "synth/l1_robust/certificate.yaml").read_text())
    rob, gate = cert["checks"]["robustness"], cert["checks"]["gate"]
    assert (
        rob["value"]
        == cert["robustness_lhs"]
        == pytest.approx(cert["calibration"]["lambda_hat"] * design["robustness_lhs"], rel=0.05)
    )  # S 0 and G_m's m unchanged: the condition scales with the inflation
    assert rob["design_value"] == design["robustness_lhs"] and rob["passed"]
    assert gate["value"] == cert["rho_v"] < gate["limit"] and gate["passed"]
    assert gate["design_value"] == design["rho_v"]
    assert cert["R0"] == cert["eps_e"] != design["R0"]
    assert cert["gamma_strict"] == pytest.approx(
        cert["R0"] / (1 - cert["s_times_norm_phi_xy"]), rel=1e-12
    )


def test_stated_alpha_is_met_by_exchangeable_synthetic_flights(tmp_path: Path) -> None:
    """Flights, not scores: 1000 draws of 20 calibration flights and one new flight, each a
    tick log of one family (a random flight-level scale for perception errors with a burst of
    velocity outliers, for the disturbance through the plant, and a reference offset), scored
    by the calibration's own ``score_flight`` on a certified controller's premise. The new
    flight, read by ``check_assumptions`` under the premise inflated by ``lambda_hat``, breaks
    it (dense, disturbance, outliers, or its reference beyond Delta) at a rate within the
    binomial interval of alpha 0.1 (split conformal at n = 20: 1 - 19/21 = 0.095); a new
    flight drawn 1.3 times wider breaks it far more often."""
    from dataclasses import replace

    from qsls.pipeline.calibrate.core import score_flight
    from qsls.pipeline.evaluate.assumptions import FlownLog, check_assumptions
    from qsls.pipeline.evaluate.certified import certified_premise
    from tests.controllerfixtures import gated

    folder = gated(tmp_path / "c").folder
    c = certified_premise(folder)
    assert c is not None
    c = replace(c, numbers=replace(c.numbers, delta=0.05))  # a reference to inflate too
    rng = np.random.default_rng(11)
    k = 24
    t = np.arange(k) * 0.1

    def distance(q: np.ndarray) -> np.ndarray:
        return np.abs(q[:, :3]).max(axis=1)  # to the training states {0}, positions

    def flight(wider: float = 1.0) -> FlownLog:
        s = np.exp(rng.normal(0.0, 0.35, 3)) * wider  # each flight's own scales
        ref = np.zeros((k, 6))
        ref[:, :3] = rng.uniform(-0.04, 0.04, 3) * s[2]
        x = np.zeros((k, 6))
        x[0] = ref[0]
        u = np.tile(c.u_hover, (k, 1))
        w = (c.H @ rng.uniform(-1, 1, (6, k)) * 0.6 * c.numbers.eps_w * s[1]).T
        for i in range(k - 1):
            x[i + 1] = c.A @ x[i] + w[i]
        e = rng.normal(0.0, 0.3 * c.numbers.eps, (k, 6)) * s[0]
        burst = rng.integers(0, k - 3)
        e[burst : burst + rng.integers(0, 4), 3] = 0.5  # velocity outliers within eps_o
        return FlownLog(t, x, x + e, u, ref, np.zeros((k, 3)))

    def breaks(log: FlownLog, lam: float) -> bool:
        big = replace(c, numbers=cal.inflate(c.numbers, lam))
        row = check_assumptions(log, big, distance)
        held = all(row[f"{a}_holds"] for a in ("dense", "disturbance", "outliers"))
        return not held or float(distance(log.ref).max()) > big.numbers.delta

    draws, n, misses, wide = 1000, 20, 0, 0
    for _ in range(draws):
        scores = [score_flight(flight(), c, distance)["score"] for _ in range(n)]
        lam = conformal.calibrated_quantile(scores, 0.1, "conformal")
        misses += breaks(flight(), lam)
        wide += breaks(flight(1.3), lam)  # not exchangeable: the check must see it
    lo, hi = binom.ppf([0.0005, 0.9995], draws, 0.1) / draws
    assert lo <= misses / draws <= hi, (misses, lo, hi)
    assert wide / draws > hi, wide


def test_a_range_flights_score_keeps_the_disturbance_and_drops_the_reference() -> None:
    """A range flight flies an offset reference on purpose (its reference term is left out),
    but the disturbance bound is assumed out to rho*: a range flight whose realized
    disturbance exceeds eps_w raises its score (paper_sim_camera's first degraded calibration
    had one at 1.10, left out by a perception-only score)."""
    from qsls.pipeline.calibrate.core import range_score

    parts = {"dense": 0.9, "disturbance": 1.098, "reference": 13.4, "outliers": 0.0}
    assert range_score(parts) == 1.098
    assert range_score({**parts, "disturbance": 0.5}) == 0.9
    assert range_score({**parts, "outliers": 2.0}) == 2.0


def test_fly_refuses_the_seeds_a_calibration_flew(quickstart_session, tmp_path: Path) -> None:
    """Issue 50, item 5: a flight on a seed the calibration flew (the quickstart's calibration,
    range and validation seeds) is that flight again, not fresh evidence: ``qsls fly``
    refuses it in one line; a fresh seed is not refused."""
    import subprocess
    import sys

    import yaml

    run = quickstart_session[0] / "runs" / "quickstart"
    cert = run / "calibrate" / "regular" / "l1_robust"
    rec = yaml.safe_load((cert / "certificate.yaml").read_text())["calibration"]
    c, r, v = CAL_SEED, QUICKSTART_CAL["range_seed"], QUICKSTART_CAL["validation_seed"]
    assert {c, r + 19, v + 19} <= set(rec["evidence_seeds"]) and len(rec["evidence_seeds"]) == 60
    for seeds, refused in ((str(v + 5), True), (str(r), True), (str(c + 19), True)):
        proc = subprocess.run(
            [sys.executable, "-m", "qsls.cli.main", "fly", "--model", str(run / "fit"),
             "--controller", str(cert), "--seeds", seeds, "--out", str(tmp_path / seeds)],
            capture_output=True, text=True, cwd=tmp_path,
        )  # fmt: skip
        err = proc.stderr.strip()
        assert (proc.returncode != 0) == refused, err
        assert "flown by l1_robust's calibration" in err and len(err.splitlines()) == 1
        assert not (tmp_path / seeds).exists()
    from qsls.pipeline.evaluate.certified import refuse_evidence_seeds

    refuse_evidence_seeds([cert], [0, c - 1, c + 20, r + 1000])  # fresh: no error


def test_the_summary_names_the_premise_quantity_that_set_lambda_hat():
    """``lambda_set_by``: the largest part of the flight whose score is ``lambda_hat`` (issue 47:
    on the quickstart every calibration score was the reference's term, so its quantile said
    nothing of the noise; the report says so)."""
    rows = [
        {"role": "calibration", "dense": 0.4, "disturbance": 0.5, "reference": 0.86, "outliers": 0.0, "score": 0.86},
        {"role": "calibration", "dense": 0.9, "disturbance": 0.5, "reference": 0.86, "outliers": 0.25, "score": 0.9},
        {"role": "range", "dense": 0.5, "disturbance": 1.1, "reference": 9.0, "outliers": 0.0, "score": 1.1},
    ]  # fmt: skip
    assert set_by(rows, 0.9) == "dense (calibration flight)"
    assert set_by(rows, 0.86) == "reference (calibration flight)"
    assert set_by(rows, 1.1) == "disturbance (range flight)"  # scored without the reference
    assert set_by(rows, 0.7) == "" and set_by(rows, math.inf) == ""
