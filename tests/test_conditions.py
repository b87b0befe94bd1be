"""Conditions as a stated family (docs/calibration.md): each calibration flight's conditions
drawn from the family by its seed, the certificate's statement, and every flight's recorded
conditions compared with it (issue 47)."""

from __future__ import annotations

import pytest

from qsls.pipeline.calibrate.options import CalibrateOptions
from qsls.pipeline.core.config import merge
from qsls.pipeline.evaluate.conditions import (
    ConditionFamily,
    draw,
    drawn,
    flight_conditions,
    outside_family,
    stated,
)
from qsls.pipeline.sim.options import SimOptions

BASE = SimOptions.model_validate(
    {"duration": 15, "reference": {"kind": "circle", "radius": 1.0, "period": 5.0}}
).model_dump(mode="json")
FAMILY = ConditionFamily(mass=(0.97, 1.03), period=(4.5, 5.5), center_offset=0.2)


def _flight(over: dict) -> dict:
    return flight_conditions(SimOptions.model_validate(merge(BASE, over)).model_dump(mode="json"))


def test_a_point_family_changes_no_flight_and_records_nothing():
    assert ConditionFamily().point
    assert draw(ConditionFamily(), 5, BASE) == {} and drawn(ConditionFamily(), BASE) == {}


def test_each_flight_draws_its_own_conditions_by_its_seed_and_the_controller_keeps_its_mass():
    a, b = draw(FAMILY, 7, BASE), draw(FAMILY, 8, BASE)
    assert a == draw(FAMILY, 7, BASE) and a != b  # by seed, deterministic
    masses = [draw(FAMILY, s, BASE)["vehicle"]["mass"] / 0.256 for s in range(200)]
    assert 0.97 <= min(masses) < 0.975 and 1.025 < max(masses) <= 1.03  # spans the range
    assert a["px4"]["controller_mass"] == 0.256  # the vehicle is heavier, the controller not told
    opts = SimOptions.model_validate(merge(BASE, a))
    assert opts.px4.controller_mass == 0.256 and opts.vehicle.mass == a["vehicle"]["mass"]
    cx, cy = a["reference"]["center"]
    assert (cx**2 + cy**2) ** 0.5 <= 0.2 and 4.5 <= a["reference"]["period"] <= 5.5
    assert drawn(FAMILY, merge(BASE, a))["mass_kg"] == pytest.approx(a["vehicle"]["mass"])


def test_flights_drawn_from_the_family_lie_inside_it():
    statement = stated(FAMILY, BASE)
    for s in range(30):
        assert outside_family(statement, _flight(draw(FAMILY, s, BASE))) == []


@pytest.mark.parametrize(
    ("over", "says"),
    [
        ({"vehicle": {"mass": 0.256 * 1.2}}, "mass 0.3072 kg, calibrated at [0.2483, 0.2637] kg (+16.5 % beyond)"),
        ({"vehicle": {"mass": 0.256 * 0.9}}, "(-7.2 % beyond)"),
        ({"reference": {"kind": "figure8"}}, "reference.kind 'figure8', calibrated at 'circle'"),
        ({"reference": {"period": 4.0}}, "period 4 s, calibrated at [4.5, 5.5] s (-11.1 % beyond)"),
        ({"reference": {"radius": 1.2}}, "radius 1.2 m, calibrated at 1 m (+20.0 % beyond)"),
        ({"reference": {"center": [0.3, 0.0]}}, "reference centre 0.3 m from the calibrated centre (up to 0.2 m)"),
        ({"vio": {"noise": False}}, "vio.noise False, calibrated at True"),
        ({"vehicle": {"aero": False}}, "vehicle.aero False, calibrated at True"),
    ],
)  # fmt: skip
def test_a_flight_outside_the_family_is_flagged_with_the_condition_and_how_far(over, says):
    why = outside_family(stated(FAMILY, BASE), _flight(over))
    assert len(why) == 1 and says in why[0], why


def test_a_family_range_must_be_ordered_finite_and_positive():
    for bad in ({"mass": [1.1, 0.9]}, {"period": [0, 5]}, {"mass": [1.0, float("nan")]}):
        with pytest.raises(ValueError):
            ConditionFamily.model_validate(bad)
    assert CalibrateOptions.model_validate({"family": {"mass": [0.9, 1.1]}}).family.mass == (
        0.9,
        1.1,
    )


def test_the_promise_names_the_vehicle_family_it_was_calibrated_over():
    from qsls.pipeline.evaluate.verdict import conditions_text

    c = {"perception": "regular", "vehicle": {"mass": 0.256}}
    assert conditions_text(c).endswith("the 0.256 kg vehicle")
    c["family"] = stated(FAMILY, BASE)["family"]
    assert "a vehicle of 0.2483 to 0.2637 kg" in conditions_text(c)
    c["family"] = stated(WINDY, BASE)["family"]
    assert "wind of 0 to 1.5 m/s" in conditions_text(c), conditions_text(c)


WINDY = ConditionFamily(
    mass=(0.97, 1.03), period=(4.5, 5.5), center_offset=0.2,
    wind=(0.0, 1.5), gust=(0.0, 0.3), thrust_constant=(0.95, 1.05), sag=(0.0, 0.05),
)  # fmt: skip


def test_the_wind_thrust_constant_and_sag_are_drawn_by_the_seed_and_recorded():
    draws = [draw(WINDY, s, BASE) for s in range(200)]
    assert draws[7] == draw(WINDY, 7, BASE) and draws[7] != draws[8]
    # drawn after the mass and the reference: those stay the draws they were
    for s in (0, 7, 11):
        old, new = draw(FAMILY, s, BASE), draws[s]
        assert new["vehicle"]["mass"] == old["vehicle"]["mass"]
        assert new["reference"] == old["reference"]
    speeds = [d["wind"]["speed"] for d in draws]
    dirs = [d["wind"]["direction_deg"] for d in draws]
    tcs = [d["vehicle"]["thrust_constant"] for d in draws]
    sags = [d["vehicle"]["sag"] for d in draws]
    assert 0 <= min(speeds) < 0.05 and 1.45 < max(speeds) <= 1.5
    assert min(dirs) < 20 and max(dirs) > 340  # uniform over the circle unless stated
    assert 0.95 <= min(tcs) < 0.955 and 1.045 < max(tcs) <= 1.05
    assert 0.0 <= min(sags) < 0.002 and 0.048 < max(sags) <= 0.05
    flown = merge(BASE, draws[7])
    rec = drawn(WINDY, flown)
    assert rec["wind_mps"] == draws[7]["wind"]["speed"]
    assert rec["wind_dir_deg"] == draws[7]["wind"]["direction_deg"]
    assert rec["gust_mps"] == draws[7]["wind"]["gust"]
    assert rec["thrust_constant"] == draws[7]["vehicle"]["thrust_constant"]
    assert rec["sag"] == draws[7]["vehicle"]["sag"]
    assert "wind_mps" not in drawn(FAMILY, flown)  # a family without them: the columns as before
    st = stated(WINDY, BASE)["family"]
    assert st["wind"] == [0.0, 1.5] and st["wind_direction"] == [0.0, 360.0]
    assert st["thrust_constant"] == [0.95, 1.05] and st["sag"] == [0.0, 0.05]
    statement = stated(WINDY, BASE)
    for d in draws[:30]:
        assert outside_family(statement, _flight(d)) == []


@pytest.mark.parametrize(
    ("over", "says"),
    [
        ({"wind": {"speed": 3.1}}, "wind 3.1 m/s, calibrated at [0, 1.5] m/s (+106.7 % beyond)"),
        ({"wind": {"speed": 1.0, "gust": 0.5}}, "gust 0.5 m/s, calibrated at [0, 0.3] m/s (+66.7 % beyond)"),
        ({"vehicle": {"thrust_constant": 1.1}}, "thrust constant 1.1, calibrated at [0.95, 1.05] (+4.8 % beyond)"),
        ({"vehicle": {"sag": 0.1}}, "sag 0.1, calibrated at [0, 0.05] (+100.0 % beyond)"),
    ],
)  # fmt: skip
def test_a_wind_thrust_or_sag_outside_the_family_is_flagged_with_how_far(over, says):
    why = outside_family(stated(WINDY, BASE), _flight(over))
    assert why == [says]


def test_a_certificate_that_states_no_wind_was_calibrated_in_still_air():
    """A statement without them (a point family, or a record older than them) was flown in
    still air with nominal rotors: a windy, sagging flight lies outside it."""
    for statement in (stated(FAMILY, BASE), {"vehicle": BASE["vehicle"]}):
        why = outside_family(statement, _flight({"wind": {"speed": 1.0}, "vehicle": {"sag": 0.05}}))
        assert why == ["wind 1 m/s, calibrated at 0 m/s", "sag 0.05, calibrated at 0"], why
        assert outside_family(statement, _flight({})) == []


def test_a_stated_wind_direction_flags_a_wind_from_elsewhere_by_the_angle():
    fam = WINDY.model_copy(update={"wind_direction": (0.0, 90.0)})
    statement = stated(fam, BASE)
    inside = _flight({"wind": {"speed": 1.0, "direction_deg": 45.0}})
    assert outside_family(statement, inside) == []
    why = outside_family(statement, _flight({"wind": {"speed": 1.0, "direction_deg": -60.0}}))
    assert why == ["wind direction -60 deg, calibrated at [0, 90] deg (60 deg beyond)"]


def test_a_degenerate_range_sets_its_condition_on_every_flight():
    fam = ConditionFamily(radius=(1.2, 1.2), wind=(1.0, 1.0))
    assert not fam.point
    d = draw(fam, 3, BASE)
    assert d["reference"]["radius"] == 1.2 and d["wind"]["speed"] == 1.0
    with pytest.raises(ValueError):
        ConditionFamily(sag=(0.0, 0.9))


def test_a_windy_flight_is_outside_a_still_air_calibration_in_the_fly_tables_words():
    from qsls.pipeline.control.artifacts import Calibration
    from qsls.pipeline.evaluate.certified import outside_calibration

    statement = {"perception": "regular", "estimator": "emulator", "duration_s": 15.0,
                 **stated(WINDY, BASE)}  # fmt: skip
    cal = Calibration(
        flights=20, alpha=0.1, confidence=None, method="split conformal", conditions=statement,
        duration_s=15.0, seeds=list(range(20)), scores=[0.5] * 20, lambda_hat=0.5, rank=19,
        tested_range=1.0, nominal={}, parts={}, tolerances={}, holds=True,
    )  # fmt: skip
    flown = SimOptions.model_validate(merge(BASE, {"wind": {"speed": 3.1, "gust": 0.2}}))
    conditions = flight_conditions(flown.model_dump(mode="json"))  # as fly/flights.py records them
    why = outside_calibration(cal, "regular", 15.0, "emulator", conditions)
    assert why == "wind 3.1 m/s, calibrated at [0, 1.5] m/s (+106.7 % beyond)"
    inside = SimOptions.model_validate(merge(BASE, draw(WINDY, 4, BASE))).model_dump(mode="json")
    assert outside_calibration(cal, "regular", 15.0, "emulator", flight_conditions(inside)) == ""


PX4 = merge(BASE, {"px4": {"interface": "px4"}})
HOVER = ConditionFamily(mass=(0.9, 1.1), hover_error=(-0.02, 0.02))


def test_the_hover_estimate_error_is_drawn_for_px4s_interface_and_compared():
    from qsls.pipeline.core.errors import ConfigError
    from qsls.pipeline.evaluate.conditions import hover_error

    errs = [hover_error(draw(HOVER, s, PX4)["px4"]) for s in range(100)]
    assert -0.02 <= min(errs) < -0.018 and 0.018 < max(errs) <= 0.02  # spans the range
    assert draw(HOVER, 3, PX4) == draw(HOVER, 3, PX4)
    # the mass draw is the one a family without the estimate makes (its stream comes first)
    assert (
        draw(HOVER, 3, PX4)["vehicle"] == draw(ConditionFamily(mass=(0.9, 1.1)), 3, PX4)["vehicle"]
    )
    with pytest.raises(ConfigError, match=r"px4\.interface: px4"):
        draw(HOVER, 3, BASE)
    statement = stated(HOVER, PX4)
    for s in range(20):
        assert outside_family(statement, _flight(merge(PX4, draw(HOVER, s, PX4)))) == []
    off = _flight(merge(PX4, {"px4": {"hover_estimate": 0.47}}))
    assert outside_family(statement, off) == [
        "hover-thrust estimate error -0.06, calibrated at [-0.02, 0.02] (-200.0 % beyond)"
    ]
    # a flight through the paper's interface is outside a calibration through PX4's
    assert outside_family(statement, _flight({})) == ["interface 'paper', calibrated through 'px4'"]
    slow = _flight(merge(PX4, {"px4": {"estimator_latency_s": 0.05}}))
    assert outside_family(statement, slow) == ["px4.estimator_latency_s 0.05, calibrated at 0.0"]


def test_the_estimators_parameters_are_drawn_recorded_and_compared_with_their_ranges():
    fam = ConditionFamily(
        mass=(0.97, 1.03), estimator={"noise_velocity": (0.012, 0.018), "regular.light": (0.9, 1.0)}
    )
    a = draw(fam, 4, BASE)
    assert a["vehicle"] == draw(ConditionFamily(mass=(0.97, 1.03)), 4, BASE)["vehicle"]
    opts = SimOptions.model_validate(merge(BASE, a))
    assert 0.012 <= opts.vio.noise_velocity <= 0.018 and 0.9 <= opts.vio.regular.light <= 1.0
    assert opts.vio.regular.texture == 1.0  # the level's other parameter stays
    got = drawn(fam, opts.model_dump(mode="json"))
    assert got["vio_noise_velocity"] == opts.vio.noise_velocity
    assert got["vio_regular_light"] == opts.vio.regular.light
    statement = stated(fam, BASE)
    for s in range(20):
        assert outside_family(statement, _flight(draw(fam, s, BASE))) == []
    noisy = _flight({"vio": {"noise_velocity": 0.03}})
    assert outside_family(statement, noisy) == [
        "vio.noise_velocity 0.03, calibrated at [0.012, 0.018] (+66.7 % beyond)"
    ]
    other = _flight({"vio": {"noise_position": 0.01}})  # not ranged: compared exactly
    assert outside_family(statement, other) == ["vio.noise_position 0.01, calibrated at 0.004"]
    with pytest.raises(ValueError, match="not a numeric parameter"):
        ConditionFamily(estimator={"kind": (0.0, 1.0)})


def test_the_figure_eight_as_a_member_of_the_family():
    """``figure8: 0.25`` flies the figure-eight on about a quarter of the flights (by seed, a
    stream of its own: the other draws are those of the family without it), records which
    one each flew, states the share and accepts both kinds; a hover is still outside."""
    fam = ConditionFamily(mass=(0.97, 1.03), period=(4.5, 5.5), center_offset=0.2, figure8=0.25)
    kinds = [draw(fam, s, BASE)["reference"].get("kind", "circle") for s in range(400)]
    assert 0.2 < kinds.count("figure8") / 400 < 0.3 and set(kinds) == {"circle", "figure8"}
    for s in range(20):  # the other draws unchanged by the new member
        a, b = draw(fam, s, BASE), draw(FAMILY, s, BASE)
        a["reference"].pop("kind", None)
        assert a == b
    statement = stated(fam, BASE)
    assert (
        statement["family"]["figure8"] == 0.25 and "figure8" not in stated(FAMILY, BASE)["family"]
    )
    for s in range(30):
        flight = merge(BASE, draw(fam, s, BASE))
        assert outside_family(statement, _flight(draw(fam, s, BASE))) == []
        assert drawn(fam, flight)["figure8"] == float(flight["reference"]["kind"] == "figure8")
    assert outside_family(statement, _flight({"reference": {"kind": "hover"}})) == [
        "reference 'hover', calibrated on 'circle' and 'figure8'"
    ]
    # without the member, a figure-eight flight lies outside
    assert any(
        "figure8" in w
        for w in outside_family(stated(FAMILY, BASE), _flight({"reference": {"kind": "figure8"}}))
    )


def test_the_promise_names_the_centre_offset_the_start_and_the_figure_eight_share():
    from qsls.pipeline.evaluate.verdict import conditions_text

    fam = ConditionFamily(center_offset=0.2, figure8=0.25, start_offset=0.3)
    text = conditions_text({"perception": "regular", **stated(fam, BASE)})
    assert "its centre moved up to 0.2 m" in text
    assert "a start up to 0.3 m beside the reference" in text
    assert "the figure-eight instead on 25 % of flights" in text
    assert "figure-eight" not in conditions_text({"perception": "regular", **stated(FAMILY, BASE)})


def test_a_start_beside_the_reference_as_a_member_of_the_family():
    """``start_offset: 0.3`` starts each flight up to 0.3 m beside the reference's first point
    (uniform in the disc, by seed, on a stream of its own), records it, states it and accepts
    it; a start farther out, or any start under a family without it, lies outside."""
    fam = ConditionFamily(mass=(0.97, 1.03), period=(4.5, 5.5), center_offset=0.2, start_offset=0.3)
    starts = [draw(fam, s, BASE)["start_offset"] for s in range(300)]
    radii = [(x * x + y * y) ** 0.5 for x, y in starts]
    assert max(radii) <= 0.3 and max(radii) > 0.28 and min(radii) < 0.05
    for s in range(20):
        a = draw(fam, s, BASE)
        a.pop("start_offset")
        assert a == draw(FAMILY, s, BASE)  # the other draws unchanged by the new member
    statement = stated(fam, BASE)
    assert statement["family"]["start_offset"] == 0.3
    for s in range(30):
        d = draw(fam, s, BASE)
        flight = SimOptions.model_validate(merge(BASE, d)).model_dump(mode="json")
        assert outside_family(statement, _flight(d)) == []
        assert [drawn(fam, flight)[k] for k in ("start_x_m", "start_y_m")] == d["start_offset"]
    far = {"start_offset": [0.3, 0.3]}
    assert outside_family(statement, _flight(far)) == [
        "start 0.424 m beside the reference's first point, calibrated at up to 0.3 m"
    ]
    assert outside_family(stated(FAMILY, BASE), _flight({"start_offset": [0.1, 0.0]})) == [
        "start 0.1 m beside the reference's first point, calibrated at up to 0 m"
    ]
