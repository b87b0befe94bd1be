"""The runtime-assured flights' tables (docs/monitor.md, The fallback): the monitor's catch
share and the comparison of a controller alone, assured and PD alone, each against a count
made by hand on a small constructed table. The flights themselves are tested in
tests/test_export_monitor.py (on its certified controller)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from qsls.pipeline.evaluate.assumptions import ASSUMPTIONS
from qsls.pipeline.fly.assured import assured_comparison, catch_share, trip_columns

NAN = math.nan


def _row(flight, condition, trips, monitor_t, fails=None, crashed=False):
    """An assumption-table row: ``fails`` maps an assumption to the time it failed."""
    fails = fails or {}
    row = {"flight": flight, "condition": condition, "monitor_trips": trips,
           "monitor_t": monitor_t, "crashed": crashed}  # fmt: skip
    for a in ASSUMPTIONS:
        row[f"{a}_holds"] = a not in fails
        row[f"{a}_t"] = fails.get(a, NAN)
    row["assumptions_hold"] = not fails and not crashed
    row["first_failed"] = "crashed" if crashed and not fails else ""
    return row


def test_catch_share_against_a_hand_count():
    a = pd.DataFrame([
        _row("f1", "regular", 0, NAN),
        _row("f2", "regular", 2, 1.2),  # a trip while every check held
        _row("f3", "degraded", 1, 4.0, {"disturbance": 3.0}),  # caught, 1.0 s late
        _row("f4", "degraded", 0, NAN, {"outliers": 2.0, "dense": 1.5}),  # missed
        _row("f5", "degraded", 3, 5.5, {"nominal": 6.0, "dense": 5.0}),  # caught, 0.5 s late
        _row("f6", "regular", 0, NAN, crashed=True),  # a crash breaks no premise
    ])  # fmt: skip
    c = catch_share(a).set_index("scope")
    assert list(c.index) == ["all", "regular", "degraded"]
    assert c.loc["all", ["flights", "broken", "caught", "trips_premise_held"]].tolist() == [
        6,
        3,
        2,
        1,
    ]
    assert c.loc["all", "catch_share"] == pytest.approx(2 / 3)
    assert c.loc["all", "mean_delay_s"] == pytest.approx(0.75)
    assert c.loc["regular", ["broken", "caught", "trips_premise_held"]].tolist() == [0, 0, 1]
    assert math.isnan(c.loc["regular", "catch_share"])
    assert math.isnan(c.loc["regular", "mean_delay_s"])
    assert c.loc["degraded", ["flights", "broken", "caught"]].tolist() == [3, 3, 2]
    assert catch_share(a.iloc[:0]).empty


def _flight(controller, seed, rms, crashed=False, condition="degraded"):
    return {"flight": f"{condition}_s{seed}_{controller}", "controller": controller,
            "condition": condition, "seed": seed, "tracking_rms_m": rms,
            "tracking_max_m": 3 * rms, "perception_error_rms": 0.1, "crashed": crashed}  # fmt: skip


def test_assured_comparison_against_a_hand_count():
    flights = pd.DataFrame([
        _flight("pd", 0, 0.10), _flight("pd", 1, 0.20), _flight("pd", 2, 0.90),
        _flight("l1_robust", 0, 0.30, crashed=True), _flight("l1_robust", 1, 0.10),
        _flight("l1_robust", 2, 5.0),  # a seed the assured controller did not fly: left out
    ])  # fmt: skip
    assured = pd.DataFrame([
        {**_flight("l1_robust", 0, 0.12), "tripped": True, "trip_t": 2.0},
        {**_flight("l1_robust", 1, 0.10), "tripped": False, "trip_t": NAN},
    ])  # fmt: skip
    c = assured_comparison(flights, assured).set_index("flown")
    assert list(c.index) == ["alone", "assured", "PD alone"]
    assert c["flights"].tolist() == [2, 2, 2] and c["crashed"].tolist() == [1, 0, 0]
    np.testing.assert_allclose(c["tracking_rms_m"], [0.20, 0.11, 0.15])
    np.testing.assert_allclose(c["tracking_max_m"], [0.90, 0.36, 0.60])
    assert c.loc["assured", "switched"] == 1 and c.loc["assured", "switching_rate"] == 0.5
    assert c.loc["assured", "mean_trip_s"] == 2.0
    assert math.isnan(c.loc["alone", "switching_rate"])


def test_trip_columns_from_the_tick_record():
    t = np.arange(6) * 0.1
    got = trip_columns(["c", "c", "c", "pd", "pd", "pd"], [0, 0, 0, 2, 0, 1], t)
    assert got == {"tripped": True, "trip_tick": 3, "trip_t": pytest.approx(0.3),
                   "trip_first": "outlier count", "fallback_share": 0.5,
                   "trip_summary": "more than m outliers in T ticks (envelope count) for 0.1 s "
                                   "(from 0.3 s); deviation beyond its envelope for 0.1 s "
                                   "(from 0.5 s)"}  # fmt: skip
    # the innovation monitor's bits name their test and channel: vz's window sum (16 << 5)
    # on window 1 (1024 << 1), four ticks from 0.2 s, then the innovation outlier count (8)
    vz = (16 << 5) | (1024 << 1)
    inno = trip_columns(["c"] * 6, [0, 0, vz, vz, vz | 8, vz], t)
    assert inno["trip_first"] == "disturbance on vz" and inno["trip_tick"] == 2
    assert inno["trip_summary"] == (
        "disturbance above eps_w on vz for 0.4 s (from 0.2 s); more than m outliers in T ticks "
        "(innovation count) for 0.1 s (from 0.4 s)"
    )
    none = trip_columns(["c"] * 3, [0, 0, 0], t[:3])
    assert not none["tripped"] and none["trip_tick"] == -1 and none["fallback_share"] == 0.0


def test_report_section_reads_the_fly_stages_tables(tmp_path):
    """The report's monitor section from a fly folder: the catch share per scope and the
    assured comparison with its switching rate, each at most 8 columns."""
    from qsls.pipeline.report.facts import Facts
    from qsls.pipeline.report.monitor import section_monitor

    fly = tmp_path / "fly"
    fly.mkdir()
    a, b = (
        _row("a", "degraded", 0, NAN, {"outliers": 2.0}),
        _row("b", "degraded", 2, 3.0, {"dense": 2.5}),
    )
    b |= {"first_failed": "dense", "controller": "l1_robust"}
    a |= {"controller": "l1_robust"}
    a["monitor_summary"] = ""
    b["monitor_summary"] = "disturbance above eps_w on vz for 0.2 s (from 3.0 s)"
    pd.DataFrame([a, b]).to_parquet(fly / "assumptions.parquet")
    pd.DataFrame([_flight("pd", 0, 0.1), _flight("l1_robust", 0, 0.2)]).to_parquet(
        fly / "flights.parquet"
    )
    extra = {"status": "relaxed", "calibrated_perception": "regular", "fallback": "pd",
             "tripped": True, "trip_t": 3.0}  # fmt: skip
    pd.DataFrame([{**_flight("l1_robust", 0, 0.15), **extra}]).to_parquet(fly / "assured.parquet")
    sec = section_monitor(Facts(tmp_path, {}, {}, fly_folder="fly"), [0])
    assert sec is not None
    tables = [b for kind, b in sec.blocks if kind == "table"]
    assert len(tables) == 3 and all(len(t.columns) <= 8 for t in tables)
    assert tables[0].rows[0][:5] == ["all", 2, 2, 1, "50%"]
    # a trip explains itself: the flight that tripped, its first failing assumption, the delay
    assert tables[1].rows == [["b", "l1_robust", "degraded", "dense at 2.5 s", "3", "0.5",
                               "disturbance above eps_w on vz for 0.2 s (from 3.0 s)"]]  # fmt: skip
    assured = {r[2]: r for r in tables[2].rows}
    assert set(assured) == {"alone", "assured", "PD alone"}
    assert assured["assured"][1] == "l1_robust (relaxed)"
    assert assured["assured"][7].startswith("1 of 1 (100%), mean trip 3")
    notes = tables[2].notes
    assert len(notes) == 2 and "l1_robust is relaxed, not certified" in notes[0]
    assert "calibrated in regular perception" in notes[1] and "in degraded perception" in notes[1]
    assert section_monitor(Facts(tmp_path, {}, {}, fly_folder=""), [0]) is None


def test_per_estimator_each_assured_flight_meets_its_own_estimators_flights():
    """With an ``estimator`` column (several estimators), the comparison is per estimator:
    the camera's assured flight against the camera's flights only, and the catch share adds
    a row per estimator and per estimator and condition."""
    flights = pd.DataFrame([
        {**_flight("l1_robust", 0, 0.30), "estimator": "camera"},
        {**_flight("pd", 0, 0.20), "estimator": "camera"},
        {**_flight("l1_robust", 0, 0.10), "estimator": "emulator"},
        {**_flight("pd", 0, 0.05, crashed=True), "estimator": "emulator"},
    ])  # fmt: skip
    assured = pd.DataFrame([
        {**_flight("l1_robust", 0, 0.25), "estimator": "camera", "tripped": True, "trip_t": 1.5},
        {**_flight("l1_robust", 0, 0.10), "estimator": "emulator", "tripped": False,
         "trip_t": NAN},
    ])  # fmt: skip
    c = assured_comparison(flights, assured)
    assert c.columns[0] == "estimator" and len(c) == 6
    got = {(r.estimator, r.flown): (r.tracking_rms_m, r.crashed) for r in c.itertuples()}
    assert got == {("camera", "alone"): (0.30, 0), ("camera", "assured"): (0.25, 0),
                   ("camera", "PD alone"): (0.20, 0), ("emulator", "alone"): (0.10, 0),
                   ("emulator", "assured"): (0.10, 0), ("emulator", "PD alone"): (0.05, 1)}  # fmt: skip
    rate = c[c["flown"] == "assured"].set_index("estimator")["switching_rate"]
    assert rate.to_dict() == {"camera": 1.0, "emulator": 0.0}
    # without the column on both tables: one comparison over every flight, as before
    assert "estimator" not in assured_comparison(flights.drop(columns="estimator"), assured)
    a = pd.DataFrame([
        {**_row("c0", "degraded", 1, 2.0, {"dense": 1.0}), "estimator": "camera"},
        {**_row("c1", "regular", 0, NAN, {"dense": 1.0}), "estimator": "camera"},
        {**_row("e0", "degraded", 0, NAN, {"outliers": 1.0}), "estimator": "emulator"},
    ])  # fmt: skip
    s = catch_share(a).set_index("scope")
    assert list(s.index) == ["all", "degraded", "regular", "camera: all", "camera: degraded",
                             "camera: regular", "emulator: all", "emulator: degraded"]  # fmt: skip
    assert s.loc["camera: all", ["broken", "caught"]].tolist() == [2, 1]
    assert s.loc["camera: all", "catch_share"] == 0.5 and s.loc["emulator: all", "catch_share"] == 0
    assert s.loc["degraded", ["broken", "caught"]].tolist() == [2, 1]
