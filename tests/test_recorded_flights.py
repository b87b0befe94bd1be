"""Recorded flights as calibration flights (docs/vehicle.md): ``configs/px4_logs.yaml`` run as a
user would, every calibration, range and validation flight a PX4 ULog of the stand-in vehicle
(the exported C controller behind PX4's interface) read back by ``qsls ingest --mass``; the
tick logs the logs give against the simulator's own, the certificate, the proof that the
candidate flew each flight, and the one-line refusals."""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from qsls.pipeline.calibrate.core import score_flight
from qsls.pipeline.core.artifacts import parquet_bytes
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.ticks import TICKS_FILE, TickLog
from qsls.pipeline.errormodel.model import load_error_model, resolve_model
from qsls.pipeline.evaluate.certified import certified_premise
from qsls.pipeline.evaluate.flownby import TOLERANCE, flown_by, tolerances
from qsls.pipeline.evaluate.training import load_training

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "px4_logs.yaml"
MASS = 0.256


def qsls(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "qsls.cli.main", *args], cwd=cwd, capture_output=True, text=True
    )


@pytest.fixture(scope="module")
def px4_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``qsls run configs/px4_logs.yaml`` once: its run folder."""
    work = tmp_path_factory.mktemp("px4")
    shutil.copy(CONFIG, work / CONFIG.name)
    proc = qsls("run", CONFIG.name, cwd=work)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return work / "runs" / "px4_logs"


def standin(run: Path, role: str) -> list[str]:
    return sorted(p.name for p in (run / "calibrate" / "standin" / "flights").glob(f"{role}_*"))


@pytest.mark.slow
def test_certified_from_ulog_flights_alone(px4_run: Path) -> None:
    summary = json.loads((px4_run / "calibrate" / "calibration.json").read_text())
    (row,) = summary["certificates"]
    assert row["status"] == "certified", row["reason"]
    assert row["flights"] == 20 and row["validation_flights"] == 20
    assert row["tested_range"] >= row["rho_star"]
    # the stated alpha against fresh stand-in flights: 0 of 20 broke an assumption here
    assert row["validation_broken"] <= 2
    cert = yaml.safe_load((px4_run / "calibrate/regular/l1_robust/certificate.yaml").read_text())
    rec = cert["calibration"]
    assert rec["seeds"] == [] and len(rec["logs"]) == 20
    logs = px4_run / "calibrate" / "standin" / "logs"
    want = [
        hashlib.sha256((logs / name / "flight.ulg").read_bytes()).hexdigest()
        for name in standin(px4_run, "calibration")
    ]
    assert rec["logs"] == want  # each calibration flight's log, in the scores' order
    cond = rec["conditions"]
    assert cond["source"] == "standin" and cond["estimator"] == "emulator"
    assert cond["estimate_topic"] == "vehicle_visual_odometry"
    assert cond["vehicle"]["mass"] == MASS
    assert cond["duration_s"] == pytest.approx(15.0)  # 150 ticks of 0.1 s, as a simulated flight
    assert cond["vehicle"]["hover_source"] == "hover_thrust_estimate"
    low, high = cond["vehicle"]["hover_thrust"]  # over the flights, as their logs state it
    assert abs(low - 0.45) < 1e-7 and abs(high - 0.45) < 1e-7  # the log's float32
    assert cert["status"] == "certified"
    report = (px4_run / "report" / "report.md").read_text()
    assert "calibration flights are recorded flights of the vehicle" in report


@pytest.mark.slow
def test_the_logs_tick_logs_and_scores_equal_the_simulators(px4_run: Path) -> None:
    """What the ULog gives back (float32, the estimate by its arrival stamp, the truth
    interpolated at the tick from 120 Hz motion capture) against the simulator's own tick log
    of the same flight, and the calibration's scores against the simulator's."""
    mf, fd = resolve_model(px4_run / "fit")
    training = load_training(fd, load_error_model(mf), None)
    premise = certified_premise(px4_run / "synth" / "l1_robust")
    scores = pd.read_parquet(px4_run / "calibrate" / "scores.parquet").set_index("flight")
    worst: dict[str, float] = {}
    worst_score = 0.0
    names = standin(px4_run, "calibration") + standin(px4_run, "range")
    assert len(names) == 40
    for name in names:
        sim = TickLog.read(px4_run / "calibrate" / "standin" / "logs" / name / TICKS_FILE)
        log = TickLog.read(px4_run / "calibrate" / "standin" / "flights" / name / TICKS_FILE)
        assert np.array_equal(sim.t, log.t)
        for k in ("x", "y", "u", "ref", "uff"):
            a, b = getattr(sim, k), getattr(log, k)
            scale = np.array([1, 1, MASS * 9.81]) if k == "u" else 1.0
            worst[k] = max(worst.get(k, 0.0), float(np.max(np.abs(a - b) / scale)))
        want = score_flight(sim, premise, training.distance)
        have = scores.loc[name]
        for part in ("dense", "disturbance", "outliers", "reached"):
            worst_score = max(worst_score, abs(have[part] - want[part]) / max(want[part], 1e-9))
    # float32 of positions of a few metres: 1e-6; the truth's interpolation between 120 Hz
    # samples: 1e-5 on the velocity
    assert worst["y"] < 2e-6 and worst["ref"] < 2e-6 and worst["uff"] < 1e-7
    assert worst["u"] < 1e-6
    assert worst["x"] < 5e-5
    assert worst_score < 1e-3, worst_score


@pytest.mark.slow
def test_flights_not_flown_by_the_candidate_are_refused(px4_run: Path, tmp_path: Path) -> None:
    """The PD's flight, and the same taps behind another gate, are not the candidate's: by the
    identity the log carries, and by the replay alone."""
    cand = px4_run / "synth" / "l1_robust"
    mine = px4_run / "calibrate" / "standin" / "flights" / standin(px4_run, "validation")[0]
    facts = json.loads((mine / "manifest.json").read_text())["results"]["ticks"]
    log = TickLog.read(mine / TICKS_FILE)
    ok = flown_by(log, cand, MASS, facts["stamps"])
    assert ok.flown and ok.max_difference < TOLERANCE / 10, ok
    # the same taps behind a narrower gate, its certificate edited by hand: refused on load
    # (every reader recomputes the certificate from its taps and premise: docs/verify.md),
    # before any replay could take the flight for its own
    other = tmp_path / "l1_gate"
    shutil.copytree(cand, other)
    cert = yaml.safe_load((other / "certificate.yaml").read_text())
    cert["gate"] = 0.05
    (other / "certificate.yaml").write_text(yaml.safe_dump(cert, sort_keys=False))
    with pytest.raises(InputError, match="is not what its taps and premise give"):
        flown_by(log, other, MASS, facts["stamps"])
    assert ok.max_difference * 5 < tolerances(log, cand, np.array([1, 1, MASS * 9.81])).min()
    # the PD's held-out flight, ingested with the mass, through the command line
    ulg = px4_run / "simulate" / "heldout_1" / "flight.ulg"
    pd_dir = tmp_path / "pd_flight"
    proc = qsls("ingest", str(ulg), "--mass", str(MASS), "--align", "none", "--time-offset", "0",
                "--out", str(pd_dir), cwd=tmp_path)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    proc = qsls("calibrate", "-m", str(px4_run / "fit"), "--controllers", str(px4_run / "synth"),
                "--only", "l1_robust", "-o", str(tmp_path / "cal"), "--recorded", str(pd_dir),
                cwd=tmp_path)  # fmt: skip
    assert proc.returncode != 0 and "Traceback" not in proc.stderr
    err = proc.stderr.strip()
    assert "not flown by this controller" in err and "names controller pd" in err, err
    assert len(err.splitlines()) == 1 and not (tmp_path / "cal").exists()
    # and by the replay alone: the PD's first command is not the candidate's
    pd_log = TickLog.read(pd_dir / TICKS_FILE)
    by_replay = flown_by(pd_log, cand, MASS, {})
    assert not by_replay.flown and by_replay.tick is not None and by_replay.tick <= 1


@pytest.mark.slow
def test_recorded_calibration_refusals(px4_run: Path, tmp_path: Path) -> None:
    """One line each, nothing written: one log twice, a design flight, a flight without a tick
    log, flights of two masses."""
    flights = px4_run / "calibrate" / "standin" / "flights"
    a, b = (flights / n for n in standin(px4_run, "calibration")[:2])
    twin = tmp_path / "twin"
    shutil.copytree(a, twin)
    plain, heavy, design = tmp_path / "plain", tmp_path / "heavy", tmp_path / "design"
    ulg = px4_run / "calibrate" / "standin" / "logs" / b.name / "flight.ulg"
    base = ["--align", "none", "--time-offset", "0"]
    assert qsls("ingest", str(ulg), *base, "--out", str(plain), cwd=tmp_path).returncode == 0
    assert qsls("ingest", str(ulg), *base, "--mass", "0.3", "--out", str(heavy),
                cwd=tmp_path).returncode == 0  # fmt: skip
    train = px4_run / "simulate" / "train_1" / "flight.ulg"
    assert qsls("ingest", str(train), *base, "--mass", str(MASS), "--out", str(design),
                cwd=tmp_path).returncode == 0  # fmt: skip
    cases = {
        "come from one log": [a, twin],
        "is a design flight": [a, design],
        "no tick log": [a, plain],
        "vehicle mass 0.3": [a, heavy],
    }
    for want, given in cases.items():
        # repeated, the second comma-separated (both read)
        args = ["--recorded", str(given[0]), "--recorded", f"{given[1]},"]
        out = tmp_path / f"cal_{len(want)}"
        proc = qsls("calibrate", "-m", str(px4_run / "fit"), "--controllers",
                    str(px4_run / "synth"), "-o", str(out), *args, cwd=tmp_path)  # fmt: skip
        err = proc.stderr.strip()
        assert proc.returncode != 0 and want in err and len(err.splitlines()) == 1, (want, err)
        assert not out.exists()
    # two flights whose folders share a name are told apart by their parents
    for parent, src in (("day1", a), ("day2", b)):
        shutil.copytree(src, tmp_path / parent / "f01")
    out = tmp_path / "same_names"
    proc = qsls("calibrate", "-m", str(px4_run / "fit"), "--controllers", str(px4_run / "synth"),
                "-o", str(out), "--recorded", str(tmp_path / "day1" / "f01"), "--recorded",
                str(tmp_path / "day2" / "f01"), cwd=tmp_path)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert sorted(pd.read_parquet(out / "scores.parquet")["flight"]) == ["day1/f01", "day2/f01"]
    # --mass on a log that is not a ULog
    text = tmp_path / "vio.tum"
    text.write_text("".join(f"{k * 0.1} 0 0 1 0 0 0 1\n" for k in range(50)))
    proc = qsls("ingest", "--vio", str(text), "--truth", str(text), "--mass", "0.3", "--out",
                str(tmp_path / "x"), cwd=tmp_path)  # fmt: skip
    assert proc.returncode != 0 and "PX4 ULog" in proc.stderr


def test_recorded_options_the_stage_cannot_calibrate_on(tmp_path: Path) -> None:
    """Refused in one line before anything is read (the error model, the controllers and the
    flights named here do not exist) or written, whoever flies them: validation flights without
    calibration ones (given, or beside ``--source standin``), recorded or stand-in flights under
    two conditions; with both wrong, the missing calibration flights are said."""
    a = str(tmp_path / "flight")
    two = ["--conditions", "regular,degraded"]
    cases = [
        ("need recorded calibration flights", ["--recorded-validation", a]),
        ("need recorded calibration flights", ["--recorded-validation", a, "--source", "standin"]),
        ("need recorded calibration flights", ["--recorded-validation", a, *two]),
        ("give one condition", ["--recorded", a, *two]),
        ("give one condition", ["--source", "standin", *two]),
    ]
    for i, (want, args) in enumerate(cases):
        out = tmp_path / f"cal_{i}"
        proc = qsls("calibrate", "-m", str(tmp_path / "fit"), "--controllers",
                    str(tmp_path / "synth"), "-o", str(out), *args, cwd=tmp_path)  # fmt: skip
        err = proc.stderr.strip()
        assert proc.returncode == 2 and want in err and len(err.splitlines()) == 1, (args, err)
        assert not out.exists()


@pytest.mark.slow
def test_evaluate_flown_by_reads_a_recorded_flight_as_a_simulated_one(
    px4_run: Path, tmp_path: Path
) -> None:
    """``qsls evaluate --flown-by`` on recorded flights: the candidate's own validation flight
    gets every assumption checked from its tick log, the values equal to those the calibration
    wrote; the PD's flight is named as not flown by it, not blamed on it."""
    flights = px4_run / "calibrate" / "standin" / "flights"
    own = flights / standin(px4_run, "validation")[0]
    pd_dir = tmp_path / "pd_flight"
    ulg = px4_run / "simulate" / "heldout_1" / "flight.ulg"
    assert qsls("ingest", str(ulg), "--mass", str(MASS), "--align", "none", "--time-offset",
                "0", "--out", str(pd_dir), cwd=tmp_path).returncode == 0  # fmt: skip
    cert = px4_run / "calibrate" / "regular" / "l1_robust"
    out = tmp_path / "ev"
    proc = qsls("evaluate", "--model", str(px4_run / "fit"), "--controller", str(cert),
                "--flights", str(own), "--flights", str(pd_dir), "--flown-by", "l1_robust",
                "--no-figures", "--out", str(out), cwd=tmp_path)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    rows = pd.read_parquet(out / "assumptions.parquet")
    assert list(rows["flight"]) == [own.name]
    mine = rows.iloc[0]
    validation = pd.read_parquet(px4_run / "calibrate" / "validation.parquet")
    want = validation[validation["flight"] == own.name].iloc[0]
    assert bool(mine["assumptions_hold"]) == bool(want["assumptions_hold"])
    shared = [c for c in validation.columns if c in rows.columns and c.endswith("_value")]
    assert len(shared) >= 3, (list(rows.columns), list(validation.columns))
    for col in shared:
        assert mine[col] == pytest.approx(want[col], rel=1e-12, nan_ok=True), col
    warnings = json.dumps(json.loads((out / "evaluation.json").read_text()))
    assert f"{pd_dir}: not flown by l1_robust" in warnings


@pytest.mark.slow
def test_a_tick_log_names_its_controller_and_its_ticks_must_be_the_controllers(
    px4_run: Path, tmp_path: Path
) -> None:
    """``--flown-by`` refuses a tick log that names another controller (or another
    controller.npz), or whose ticks are not the controller's dt."""
    from qsls.pipeline.evaluate.certified import load_bounds
    from qsls.pipeline.evaluate.ownlog import own_log

    (bound,) = load_bounds([px4_run / "calibrate" / "regular" / "l1_robust"])
    sim = px4_run / "calibrate" / "standin" / "logs" / standin(px4_run, "validation")[0]
    log = TickLog.read(sim / TICKS_FILE)
    assert log.controller == "l1_robust" and len(log.controller_sha256) == 64
    assert own_log(sim, sim / TICKS_FILE, "", bound)[0] is not None
    cases = {
        "flown by pd": dict(controller="pd", controller_sha256=""),
        "its log's sha256": dict(controller_sha256="0" * 64),
    }
    for said, change in cases.items():
        folder = tmp_path / said.replace(" ", "_").replace("'", "")
        folder.mkdir()
        other = TickLog(log.t, log.x, log.y, log.u, log.ref, log.uff, **change)
        (folder / TICKS_FILE).write_bytes(parquet_bytes(other.frame()))
        got, why = own_log(folder, folder / TICKS_FILE, "", bound)
        assert got is None and said in why, why
    half = tmp_path / "every_other"
    half.mkdir()
    sub = TickLog(*(a[::2] for a in (log.t, log.x, log.y, log.u, log.ref, log.uff)))
    (half / TICKS_FILE).write_bytes(parquet_bytes(sub.frame()))
    got, why = own_log(half, half / TICKS_FILE, "", bound)
    assert got is None and "0.2 s apart" in why, why


@pytest.mark.slow
def test_the_same_flights_as_mavros_bags_give_the_same_scores(
    px4_run: Path, tmp_path: Path
) -> None:
    """``calibrate.standin_log: mavros``: the stand-in's flights recorded as a mavros user would
    (ROS1 bags, the controller's AttitudeTarget and reference per tick, the hover thrust given)
    score as their ULogs did, seed for seed (the same simulated flights)."""
    cfg = yaml.safe_load(CONFIG.read_text())
    cal = dict(cfg["calibrate"], flights=3, range_flights=0, validation=0, tube=0.0,
               standin_log="mavros", sim=cfg["simulate"])  # fmt: skip
    (tmp_path / "mav.yaml").write_text(yaml.safe_dump({"calibrate": cal}))
    out = tmp_path / "cal"
    proc = qsls("calibrate", "-m", str(px4_run / "fit"), "--controllers", str(px4_run / "synth"),
                "-c", "mav.yaml", "-o", str(out), cwd=tmp_path)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert (out / "standin" / "logs" / "calibration_l1_robust_s31000" / "flight.bag").is_file()
    bags = pd.read_parquet(out / "scores.parquet").set_index("flight")
    ulogs = pd.read_parquet(px4_run / "calibrate" / "scores.parquet").set_index("flight")
    assert len(bags) == 3
    # the bag's motion capture is a pose (PoseStamped): its velocity is differentiated from
    # 120 Hz positions, up to 6e-4 m/s off the ULog's odometry velocity, which moves the
    # ratios by at most 1.4e-3 here (the disturbance's velocity rows over eps_w 0.06)
    for name, row in bags.iterrows():
        for part in ("dense", "disturbance", "score"):
            assert row[part] == pytest.approx(ulogs.loc[name, part], abs=3e-3), (name, part)
        assert row["reference"] == pytest.approx(ulogs.loc[name, "reference"], rel=1e-6)
    cert = yaml.safe_load((out / "regular" / "l1_robust" / "certificate.yaml").read_text())
    assert cert["status"] == "relaxed" and "3 calibration flights" in cert["status_reason"]
    assert cert["calibration"]["conditions"]["estimate_topic"] == "/vio/odometry"


def test_commands_options_without_the_mass_are_refused(tmp_path: Path) -> None:
    text = tmp_path / "vio.tum"
    text.write_text("".join(f"{k * 0.1} 0 0 1 0 0 0 1\n" for k in range(50)))
    for flag, value in (("--hover-thrust", "0.5"), ("--commands-topic", "/x")):
        proc = qsls("ingest", "--vio", str(text), "--truth", str(text), flag, value, "--out",
                    str(tmp_path / "x"), cwd=tmp_path)  # fmt: skip
        err = proc.stderr.strip()
        assert proc.returncode == 2 and "needs the vehicle's mass: give --mass KG" in err, err
        assert len(err.splitlines()) == 1 and not (tmp_path / "x").exists()


def test_a_run_configs_recorded_list_is_its_calibration_flights() -> None:
    from qsls.pipeline.calibrate.options import CalibrateOptions

    o = CalibrateOptions.model_validate({"recorded": ["flights/a", "flights/b"]})
    assert o.recorded.calibration == [Path("flights/a"), Path("flights/b")]
    assert o.recorded.range == [] and o.recorded.given
    o = CalibrateOptions.model_validate(
        {"recorded": {"calibration": ["c"], "validation": ["v1", "v2"]}}
    )
    assert o.recorded.validation == [Path("v1"), Path("v2")]
    assert not CalibrateOptions().recorded.given


def test_a_tick_log_needs_one_frame_one_clock_and_every_command(tmp_path: Path) -> None:
    """Refused in one line: an estimate in another frame or on another clock than the truth
    (the tick log is the log's own), and a log that lost commands (a logger dropout: the
    replay cannot follow the filter through ticks the log does not hold)."""
    from qsls.pipeline.core.errors import InputError
    from qsls.pipeline.ingest.stage import one_frame

    same = {"alignment": {"yaw_rad": 0.001, "translation": [0.01, 0, 0]}, "time_offset_s": 0.0}
    one_frame(same)
    for bad, said in (
        ({"yaw_rad": 0.5236, "translation": [0, 0, 0]}, "30.00 deg"),
        ({"yaw_rad": 0.0, "translation": [2.0, 0, 0]}, "2.000 m"),
    ):
        with pytest.raises(InputError, match=said):
            one_frame({"alignment": bad, "time_offset_s": 0.0})
    with pytest.raises(InputError, match=r"clock 0\.0200 s"):
        one_frame({**same, "time_offset_s": 0.02})
    cfg = yaml.safe_load(CONFIG.read_text())["simulate"]
    cfg.update(duration=6, controller={"kind": "pd"})
    cfg["px4"] = dict(cfg["px4"], logger_dropouts=40)
    (tmp_path / "sim.yaml").write_text(yaml.safe_dump(cfg))
    assert (
        qsls(
            "simulate", "--config", "sim.yaml", "--seed", "77300", "-o", "s", cwd=tmp_path
        ).returncode
        == 0
    )
    proc = qsls("ingest", "s/flight.ulg", "--mass", str(MASS), "-o", "i", cwd=tmp_path)
    err = proc.stderr.strip()
    assert proc.returncode == 2 and "lost the controller's commands" in err, err
    assert len(err.splitlines()) == 1 and not (tmp_path / "i").exists()
    # without --mass the same log is a flight with gaps, as any log
    assert qsls("ingest", "s/flight.ulg", "-o", "j", cwd=tmp_path).returncode == 0


@pytest.mark.slow
def test_calibrate_flights_takes_folders_as_the_issue_writes_it(px4_run: Path, tmp_path: Path):
    """``qsls calibrate --flights F1 F2 F3``: ingest folders in place of a count are the
    recorded calibration flights (as ``--recorded``)."""
    flights = px4_run / "calibrate" / "standin" / "flights"
    names = standin(px4_run, "calibration")[:3]
    proc = qsls("calibrate", "-m", str(px4_run / "fit"), "--controllers", str(px4_run / "synth"),
                "--only", "l1_robust", "-o", str(tmp_path / "c"), "--flights",
                *(str(flights / n) for n in names), cwd=tmp_path)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    scores = pd.read_parquet(tmp_path / "c" / "scores.parquet")
    assert sorted(scores["flight"]) == names
    proc = qsls("calibrate", "-m", str(px4_run / "fit"), "--controllers", str(px4_run / "synth"),
                "-o", str(tmp_path / "d"), "--flights", "5", "stray", cwd=tmp_path)  # fmt: skip
    assert proc.returncode == 2 and "unexpected argument 'stray'" in proc.stderr


@pytest.mark.slow
def test_a_stated_reference_in_place_of_the_logs_setpoints(px4_run: Path, tmp_path: Path):
    """``qsls ingest LOG --mass M --reference SPEC``: the reference the controller tracked,
    stated, sampled from its first command: the stand-in's equals its logged one to the bit
    (float64, where the log's setpoints are float32), and the proof holds; a wrong one (radius
    1.2 instead of 1) is caught by the proof."""
    name = standin(px4_run, "calibration")[0]
    logs = px4_run / "calibrate" / "standin" / "logs" / name
    sim = TickLog.read(logs / TICKS_FILE)
    cand = px4_run / "synth" / "l1_robust"
    for spec, same in (("circle:radius=1,period=5,height=1", True),
                       ("circle:radius=1.2,period=5,height=1", False)):  # fmt: skip
        out = tmp_path / str(same)
        # the stand-in's controller flew its model's feedforward (the attitude plant's)
        proc = qsls("ingest", str(logs / "flight.ulg"), "--mass", str(MASS), "--reference", spec,
                    "--feedforward", "attitude", "-o", str(out), cwd=tmp_path)  # fmt: skip
        assert proc.returncode == 0, proc.stderr
        log = TickLog.read(out / TICKS_FILE)
        assert np.array_equal(log.ref, sim.ref) == same
        assert flown_by(log, cand, MASS, {}).flown == same
