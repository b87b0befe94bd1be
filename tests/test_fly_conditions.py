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

from qsls.pipeline.errormodel.model import load_error_model
from qsls.pipeline.evaluate.assumptions import check_assumptions
from qsls.pipeline.evaluate.calibrate import TickLog
from qsls.pipeline.evaluate.certified import certified_premise
from qsls.pipeline.evaluate.fly import FlyOptions, fly_evaluate
from qsls.pipeline.evaluate.training import load_training


@pytest.fixture(scope="module")
def flown(quickstart_session, tmp_path_factory):
    """The quickstart's fit, synth and regular calibration, a (short, so relaxed) calibration of
    ``l1_robust`` in degraded perception on seeds of its own, and one seed of ``l1_robust``
    flown in both conditions, runtime-assured too, with the degraded certificate given."""
    tmp = tmp_path_factory.mktemp("conditions")
    run = quickstart_session[0] / "runs" / "quickstart"
    for stage in ("fit", "synth", "calibrate"):
        shutil.copytree(run / stage, tmp / stage)
    proc = subprocess.run(
        [sys.executable, "-m", "qsls.cli.main", "calibrate", "-m", str(tmp / "fit"),
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
        se3=False, figures=False, assured=True, jobs=2,
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
        again = check_assumptions(ticks.log(), premise, training.distance)
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
        figures=False, jobs=1,
    )  # fmt: skip
    result = fly_evaluate(tmp / "fit", [regular], opts, tmp_path / "fly")
    row = result.assumptions.iloc[0]
    assert row["outside_calibration"].startswith("perception degraded, calibrated in regular")
    assert row["status"] == "certified"
