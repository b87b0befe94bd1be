"""The promise names every ranged condition of the stated family and the interface it was
calibrated through (docs/calibration.md#the-promise)."""

from __future__ import annotations

from qsls.pipeline.evaluate.verdict import conditions_text, promise


def test_the_promise_states_the_family_it_was_calibrated_over():
    conditions = {
        "perception": "regular", "estimator": "emulator",
        "reference": {"kind": "circle", "radius": 1.0},
        "vehicle": {"mass": 0.256},
        "family": {"mass": [0.2304, 0.2816], "wind": [0.0, 0.5], "sag": [0.0, 0.02],
                   "radius": [1.0, 1.0], "hover_error": [-0.02, 0.02],
                   "estimator": {"noise_velocity": [0.012, 0.018]}},
        "px4": {"interface": "px4"},
    }  # fmt: skip
    text = conditions_text(conditions)
    assert "a vehicle of 0.2304 to 0.2816 kg" in text
    assert "wind of 0 to 0.5 m/s" in text
    assert "a battery sag of 0 to 2 %" in text
    assert "a hover-thrust estimate off by -2 to 2 %" in text
    assert "reference radius" not in text  # a point range is no family: the recorded value
    assert "PX4's attitude interface" in text
    assert "the estimator's noise_velocity 0.012 to 0.018" in text
    cert = {"controller": "l1_robust", "status": "certified", "rho_star": 1.29, "gamma": 0.145,
            "calibration": {"alpha": 0.1, "duration_s": 15, "conditions": conditions}}  # fmt: skip
    assert text in promise(cert)
    # without the interface the promise does not claim it
    assert "PX4" not in conditions_text({**conditions, "px4": None})


def test_the_report_names_the_flights_flown_outside_the_calibration(tmp_path):
    import pandas as pd

    from qsls.pipeline.evaluate.verdict import ASSUMPTIONS_FILE
    from qsls.pipeline.report.facts import ControllerFacts, Facts, heldout_verdict

    (tmp_path / "fly").mkdir()
    pd.DataFrame({
        "flight": ["regular_s0", "windy_s1", "heavy_s2"], "controller": ["c"] * 3,
        "assumptions_hold": [True, True, False], "bound_held": [True] * 3,
        "first_failed": ["", "", "disturbance"],
        "outside_calibration": ["", "wind 1 m/s, calibrated at [0, 0.5] m/s (+100.0 % beyond)",
                                "mass 0.3072 kg, calibrated at [0.2304, 0.2816] kg (+9.1 % beyond)"],
    }).to_parquet(tmp_path / "fly" / ASSUMPTIONS_FILE)  # fmt: skip
    f = Facts(run_dir=tmp_path, info={"name": "x"}, stages={}, error_model={})
    f.fly_folder = "fly"
    v = heldout_verdict(f, ControllerFacts("c", "calibrate", {"status": "certified"}))
    assert "every assumption held on 2 of 3 own flights; failed: heavy_s2 (disturbance)" in v.text
    assert v.text.endswith(
        "; 2 of 3 flown outside its calibration (windy_s1: wind 1 m/s, calibrated at [0, 0.5] "
        "m/s (+100.0 % beyond))"
    )


def test_the_report_says_a_calibrated_monitors_trip_is_an_alarm_not_a_proof(tmp_path):
    import pandas as pd

    from qsls.pipeline.evaluate.assumptions import ASSUMPTIONS
    from qsls.pipeline.evaluate.verdict import ASSUMPTIONS_FILE
    from qsls.pipeline.report.document import render_html
    from qsls.pipeline.report.facts import ControllerFacts, Facts
    from qsls.pipeline.report.monitor import section_monitor

    (tmp_path / "fly").mkdir()
    rows = {
        "flight": ["s0", "s1"], "controller": ["c", "c"], "condition": ["regular"] * 2,
        "assumptions_hold": [True, False], "bound_held": [True, True],
        "first_failed": ["", "disturbance"],
        "monitor_trips": [0, 4], "monitor_t": [float("nan"), 3.5],
        "monitor_first": ["", "disturbance on vz"],
        "monitor_summary": ["", "disturbance above eps_w on vz for 0.4 s (from 3.5 s)"],
    }  # fmt: skip
    for name in ASSUMPTIONS:
        broken = name == "disturbance"
        rows[f"{name}_holds"] = [True, not broken]
        rows[f"{name}_t"] = [float("nan"), 3.0 if broken else float("nan")]
    pd.DataFrame(rows).to_parquet(tmp_path / "fly" / ASSUMPTIONS_FILE)
    f = Facts(run_dir=tmp_path, info={"name": "x"}, stages={}, error_model={})
    f.fly_folder = "fly"
    cert = {"status": "certified", "calibration": {"monitor": {"mode": "calibrated"}}}
    f.controllers = [ControllerFacts("c", "calibrate", cert)]
    page = render_html("t", "", [section_monitor(f, [0])])
    assert "c fly the innovation monitor" in page and "calibrated mode (docs/monitor.md" in page
    assert "not a proof" in page
    f.controllers = [ControllerFacts("c", "calibrate", {"status": "certified"})]
    assert "calibrated mode" not in render_html("t", "", [section_monitor(f, [0])])
