"""One certificate per perception condition in the fly stage (docs/calibration.md, "One
certificate per condition"): a flight in a condition the calibration certified for flies that
condition's certificate (its onboard monitor) and is checked against it; a flight in another
condition is checked against the controller's own and marked outside its calibration."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from qsls.pipeline.core.ticks import TickLog
from qsls.pipeline.errormodel.model import load_error_model
from qsls.pipeline.evaluate.assumptions import check_assumptions
from qsls.pipeline.evaluate.certified import certified_premise, load_controller_bound
from qsls.pipeline.evaluate.options import EvaluateOptions
from qsls.pipeline.evaluate.stage import evaluate
from qsls.pipeline.evaluate.training import load_training
from qsls.pipeline.evaluate.verdict import verdicts
from qsls.pipeline.fly.options import FlyOptions
from qsls.pipeline.fly.stage import fly_evaluate
from qsls.pipeline.sim.options import SimOptions

REGION = {"radius": 1.5, "slope": 0.05}
"""configs/quickstart.yaml's ``simulate.vio.region``."""
SIM = SimOptions.model_validate({"vio": {"region": REGION}, "px4": {"interface": "px4"}})
"""The quickstart's calibration conditions: its emulator, through PX4's interface."""


@pytest.fixture(scope="module")
def flown(quickstart_session, tmp_path_factory):
    """The quickstart's fit, synth and regular calibration, a (short, so relaxed) calibration of
    ``l1_robust`` in degraded perception on seeds of its own, and one seed of ``l1_robust``
    flown in both conditions, runtime-assured too, with the degraded certificate given."""
    tmp = tmp_path_factory.mktemp("conditions")
    run = quickstart_session[0] / "runs" / "quickstart"
    for stage in ("fit", "synth", "calibrate"):
        shutil.copytree(run / stage, tmp / stage)
    # the quickstart's emulator (its mapped region): flights of another are outside the
    # certificate's conditions (docs/calibration.md, Conditions as a stated family)
    (tmp / "cal.yaml").write_text(f"sim:\n  vio: {{region: {REGION}}}\n  px4: {{interface: px4}}\n")
    proc = subprocess.run(
        [sys.executable, "-m", "qsls.cli.main", "calibrate", "--config", str(tmp / "cal.yaml"),
         "-m", str(tmp / "fit"),
         "--controllers", str(tmp / "synth"), "--only", "l1_robust", "--conditions", "degraded",
         "--flights", "4", "--validation", "0", "--duration", "8", "--seed", "95000",
         "-o", str(tmp / "degraded_cal")],
        capture_output=True, text=True,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    regular = tmp / "calibrate" / "regular" / "l1_robust"
    degraded = tmp / "degraded_cal" / "degraded" / "l1_robust"
    opts = FlyOptions(
        seeds=[0], conditions=["regular", "degraded"], duration=8.0, controllers=["l1_robust"],
        se3=False, figures=False, assured=True, jobs=2, sim=SIM,
    )  # fmt: skip
    result = fly_evaluate(
        tmp / "fit", [regular], opts, tmp / "fly", by_condition={"degraded": [degraded]}
    )
    return tmp, regular, degraded, result


def test_each_flight_is_checked_against_its_own_conditions_certificate(flown) -> None:
    tmp, regular, degraded, result = flown
    reg_p, deg_p = certified_premise(regular), certified_premise(degraded)
    assert reg_p is not None and deg_p is not None
    # the two certificates differ (else the test could not tell them apart)
    assert deg_p.numbers.eps != pytest.approx(reg_p.numbers.eps)
    a = result.assumptions.set_index("condition")
    training = load_training(tmp / "fit", load_error_model(tmp / "fit" / "error_model.yaml"), None)
    for cond, folder in (("regular", regular), ("degraded", degraded)):
        row = a.loc[cond]
        ticks = TickLog.read(tmp / "fly" / "flights" / row["flight"])
        premise = certified_premise(folder)
        assert premise is not None
        again = check_assumptions(ticks, premise, training.distance)
        for name in ("disturbance", "dense", "outliers"):
            assert row[f"{name}_limit"] == pytest.approx(again[f"{name}_limit"], rel=1e-12)
            assert row[f"{name}_value"] == pytest.approx(again[f"{name}_value"], rel=1e-12)
        # calibrated for this very condition: inside its calibration
        assert row["outside_calibration"] == ""
    assert a.loc["regular", "status"] == "certified"
    assert a.loc["degraded", "status"] == "relaxed"  # 4 flights: too few to certify


def test_an_assured_flight_flies_its_conditions_monitor(flown) -> None:
    _, _, _, result = flown
    t = result.assured.set_index("condition")
    assert t.loc["regular", "calibrated_perception"] == "regular"
    assert t.loc["degraded", "calibrated_perception"] == "degraded"
    assert t.loc["degraded", "status"] == "relaxed"


def test_without_a_conditions_certificate_a_flight_is_marked_outside(flown, tmp_path: Path) -> None:
    tmp, regular, _, _ = flown
    opts = FlyOptions(
        seeds=[0], conditions=["degraded"], duration=8.0, controllers=["l1_robust"], se3=False,
        figures=False, jobs=1, sim=SIM,
    )  # fmt: skip
    result = fly_evaluate(tmp / "fit", [regular], opts, tmp_path / "fly")
    row = result.assumptions.iloc[0]
    assert row["outside_calibration"].startswith("perception degraded, calibrated in regular")
    assert row["status"] == "certified"


def test_a_heldout_flight_is_checked_against_its_conditions_certificate(
    flown, tmp_path: Path
) -> None:
    """The held-out check (``qsls run``'s evaluate stage) reads the same per-condition
    certificates: the degraded flight against the degraded one, the regular flight against
    the regular one; without a degraded certificate the degraded flight is checked against
    the regular one and marked outside its calibration, in the table and the verdict."""
    tmp, regular, degraded, result = flown
    a = result.assumptions.set_index("condition")
    folders = [tmp / "fly" / "flights" / a.loc[c, "flight"] for c in ("regular", "degraded")]
    opts = EvaluateOptions(figures=False)
    by = {"degraded": [degraded]}
    got = evaluate(
        folders, tmp / "fit", [regular], opts, tmp_path / "ev", conditions=["regular", "degraded"],
        by_condition=by,
    ).table.set_index("condition")  # fmt: skip
    for cond, folder in (("regular", regular), ("degraded", degraded)):
        premise = certified_premise(folder)
        assert premise is not None
        assert got.loc[cond, "eps_e"] == pytest.approx(premise.numbers.eps, rel=1e-12)
        assert got.loc[cond, "status"] == load_controller_bound(folder).status
        assert got.loc[cond, "outside_calibration"] == ""
    plain = evaluate(
        folders, tmp / "fit", [regular], opts, tmp_path / "plain",
        conditions=["regular", "degraded"],
    ).table.set_index("condition")  # fmt: skip
    reg_eps = certified_premise(regular).numbers.eps  # type: ignore[union-attr]
    assert plain.loc["degraded", "eps_e"] == pytest.approx(reg_eps, rel=1e-12)
    assert plain.loc["degraded", "outside_calibration"].startswith(
        "perception degraded, calibrated in regular"
    )
    assert plain.loc["regular", "outside_calibration"] == ""
    (line,) = [v.line() for v in verdicts(plain.reset_index())]
    assert "1 of 2 outside its calibration (perception degraded" in line
    # the controller's own tick logs: every assumption of the flight's condition's certificate
    own = evaluate(
        folders, tmp / "fit", [regular], EvaluateOptions(figures=False, flown_by="l1_robust"),
        tmp_path / "own", conditions=["regular", "degraded"], by_condition=by,
    ).assumptions  # fmt: skip
    assert own is not None and len(own) == 2
    fly_rows = result.assumptions.set_index("flight")
    for _, row in own.iterrows():
        assert row["dense_limit"] == pytest.approx(fly_rows.loc[row["flight"], "dense_limit"])
        assert row["outside_calibration"] == ""
    # without the degraded certificate, the degraded tick log is read against the regular one
    # and marked, in the table and in the verdict
    alone = evaluate(
        folders, tmp / "fit", [regular], EvaluateOptions(figures=False, flown_by="l1_robust"),
        tmp_path / "alone", conditions=["regular", "degraded"],
    ).assumptions  # fmt: skip
    assert alone is not None
    marked = alone.set_index("flight")["outside_calibration"]
    assert marked[folders[0].name] == ""
    assert marked[folders[1].name].startswith("perception degraded, calibrated in regular")
    # a flight whose estimate another estimator made than the calibration's (the quickstart
    # calibrates on the emulator) lies outside it too: the camera loop errs its own way
    cam = evaluate(
        folders, tmp / "fit", [regular], opts, tmp_path / "cam", conditions=["regular", "degraded"],
        by_condition=by, estimators=["camera", "emulator"],
    ).table.set_index("condition")  # fmt: skip
    assert cam.loc["regular", "outside_calibration"] == "estimator camera, calibrated with emulator"
    assert cam.loc["degraded", "outside_calibration"] == ""
