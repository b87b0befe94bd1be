"""The held-out check's pure core (pipeline/evaluate/core.py, issue 49): certificates already
read, flights as tables, no file touched (the certificates' folders here do not exist)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from qsls.pipeline.control.calibration_record import Calibration
from qsls.pipeline.evaluate.certified import load_controller_bound
from qsls.pipeline.evaluate.core import controller_totals, held_out_check
from qsls.pipeline.evaluate.training import TrainingData
from qsls.pipeline.ingest.flight import make_flight_frame
from tests.test_evaluate import DT, NUMBERS, circle_states, write_controller, write_fit

N = 120


def _calibration(perception: str) -> Calibration:
    return Calibration(
        flights=20, alpha=0.1, confidence=None, method="conformal",
        conditions={"perception": perception}, duration_s=100.0, seeds=list(range(20)),
        scores=[1.0] * 20, lambda_hat=1.0, rank=19, tested_range=0.5, nominal={}, parts={},
        tolerances={}, holds=True,
    )  # fmt: skip


@pytest.fixture(scope="module")
def checked(tmp_path_factory):
    from tests.controllerfixtures import l1_taps

    tmp = tmp_path_factory.mktemp("core")
    model = write_fit(tmp / "fit", circle_states(400), np.zeros((400, 6)))
    real = load_controller_bound(write_controller(tmp / "l1_robust", model, l1_taps(8, NUMBERS)))
    gone = Path("/nonexistent/calibrate")
    own = replace(real, folder=gone / "l1_robust")
    degraded = replace(
        real, folder=gone / "degraded" / "l1_robust", numbers=replace(real.numbers, eps=0.07)
    )
    stamps = (np.arange(N) * DT * 1e9).astype(np.int64)
    x = circle_states(N, z=1.1)  # 0.1 from every training state
    flights = [
        ("f_regular", make_flight_frame(stamps, x, x + 0.03)),
        ("f_degraded", make_flight_frame(stamps, x, x + 0.06)),
    ]
    training = TrainingData.build(circle_states(400), [1.0] * 6)
    table, samples = held_out_check(
        flights, [own], {("degraded", "l1_robust"): degraded}, training,
        ["regular", "degraded"], ["emulator", "emulator"],
        {own.folder: _calibration("degraded"), degraded.folder: None},
    )  # fmt: skip
    return table, samples


def test_each_flight_is_checked_against_its_conditions_certificate(checked):
    table, _ = checked
    assert list(table["flight"]) == ["f_regular", "f_degraded"]
    assert list(table["condition"]) == ["regular", "degraded"]
    assert list(table["eps_e"]) == [0.05, 0.07]  # the controller's own, the degraded one's
    assert table["max_distance_to_training"].to_numpy() == pytest.approx([0.1, 0.1], abs=1e-12)
    assert table["max_error_norm"].to_numpy() == pytest.approx([0.03, 0.06], abs=1e-12)
    # the premise eps_e + S d = 0.05 + 0.05 * 0.1 = 0.055 holds for 0.03, not for 0.06 < 0.075
    assert list(table["premise_holds"]) == [True, True]
    assert table["max_premise_ratio"].to_numpy() == pytest.approx(
        [0.03 / 0.055, 0.06 / 0.075], rel=1e-12
    )


def test_the_calibration_records_given_decide_outside_calibration(checked):
    table, _ = checked
    # the regular flight against a certificate calibrated on degraded flights; the degraded
    # flight against an uncalibrated one
    assert "degraded" in table["outside_calibration"].iloc[0]
    assert table["outside_calibration"].iloc[1] == ""


def test_recorded_flights_check_the_premise_only_and_totals_count_them(checked):
    table, samples = checked
    assert not table["theorem_applies"].any()
    assert all(v.startswith("premise only (a recorded flight") for v in table["verdict"])
    assert len(samples) == 2 * N and set(samples["flown_by"]) == {""}
    (tot,) = controller_totals(table)
    assert tot["flights"] == 2 and tot["theorem_flights"] == 0
    assert tot["max_error_norm"] == pytest.approx(0.06, abs=1e-12)
