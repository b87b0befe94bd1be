"""Conditions as a stated family (docs/calibration.md): each calibration flight's conditions
drawn from the family by its seed, the certificate's statement, and every flight's recorded
conditions compared with it (issue 47)."""

from __future__ import annotations

import pytest

from qsls.pipeline.core.config import merge
from qsls.pipeline.evaluate.conditions import (
    ConditionFamily,
    draw,
    drawn,
    flight_conditions,
    outside_family,
    stated,
)
from qsls.pipeline.evaluate.options import CalibrateOptions
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
    assert conditions_text(c).endswith("a vehicle of 0.2483 to 0.2637 kg")
