"""The simulator's conditions the controller is not told (issue 47, item 2): a steady wind
and its gust through RotorPy's drag model, the rotors' thrust constant and a battery's sag
(docs/calibration.md, Conditions as a stated family)."""

from __future__ import annotations

import numpy as np
import pytest

from qsls.pipeline.core.errors import ConfigError
from qsls.pipeline.sim.closedloop import fly
from qsls.pipeline.sim.options import FlightOptions, SimOptions, VehicleOptions, WindOptions
from qsls.pipeline.sim.vehicle import QUAD_256G, Vehicle
from qsls.pipeline.sim.wind import wind_series

G = 9.81
HOVER = {"reference": {"kind": "hover"}, "controller": {"kind": "pd", "feedback": "truth"}}


def _hover(duration: float, **over) -> FlightOptions:
    return FlightOptions.model_validate({"duration": duration, **HOVER, **over})


def _drag_at_hover(wind: float) -> float:
    """The drag model by hand at level hover in a wind ``wind`` (m/s, along body x): rotor
    drag ``4 k_d omega_h w`` plus parasitic ``c_Dx w^2``, per unit mass."""
    p = QUAD_256G
    omega = np.sqrt(p["mass"] * G / (4 * p["k_eta"]))
    return (4 * p["k_d"] * omega * wind + p["c_Dx"] * wind**2) / p["mass"]


def test_still_air_and_nominal_rotors_leave_every_dump_as_it_was():
    dump = SimOptions().model_dump(mode="json")
    assert "wind" not in dump
    assert "thrust_constant" not in dump["vehicle"] and "sag" not in dump["vehicle"]
    windy = SimOptions.model_validate({"wind": {"speed": 1.0}, "vehicle": {"sag": 0.05}})
    assert windy.model_dump(mode="json")["wind"]["speed"] == 1.0
    assert windy.model_dump(mode="json")["vehicle"]["sag"] == 0.05
    assert wind_series(WindOptions(), 3, np.zeros(4)) is None


def test_the_drag_model_puts_the_hand_computed_acceleration_on_a_hovering_vehicle():
    veh = Vehicle()
    s = veh.hover_state(np.array([0.0, 0.0, 1.0]))
    for w in (1.0, 2.0):
        s[13:16] = (w, 0.0, 0.0)
        acc = veh.derivative(s, s[16:20])[3:6]
        assert acc[0] == pytest.approx(_drag_at_hover(w), rel=1e-9)  # 0.249, 0.507 m/s^2
        assert acc[1] == pytest.approx(0.0, abs=1e-12)
        # translational lift 4 k_h w^2 / m lifts it
        assert acc[2] == pytest.approx(4 * QUAD_256G["k_h"] * w**2 / QUAD_256G["mass"], rel=1e-6)


@pytest.mark.parametrize(("speed", "direction"), [(1.0, 0.0), (2.0, 90.0)])
def test_a_steady_wind_makes_the_vehicle_lean_into_it_by_the_drag_model(speed, direction):
    f = fly(_hover(6.0, wind={"speed": speed, "direction_deg": direction}))
    u = f.ctrl_u[-10:].mean(axis=0)  # settled: the tilt holds the drag
    tilt_acc = np.array([-G * u[0], G * u[1]])  # paper's B: vx' = -g pitch, vy' = +g roll
    d = np.radians(direction)
    expected = -_drag_at_hover(speed) * np.array([np.cos(d), np.sin(d)])
    np.testing.assert_allclose(tilt_acc, expected, atol=0.02 * _drag_at_hover(speed))
    drift = (f.x[-1, :2] - f.ref[-1, :2]) @ np.array([np.cos(d), np.sin(d)])
    assert drift > 0.05 * speed  # the PD has no integral: blown downwind


def test_thrust_constant_and_sag_need_the_hand_computed_thrust_command():
    mg = QUAD_256G["mass"] * G
    strong = fly(_hover(8.0, vehicle={"thrust_constant": 1.05}))  # settled after 6 s
    assert strong.ctrl_u[-10:, 2].mean() == pytest.approx(mg / 1.05, rel=3e-3)
    sagging = fly(_hover(8.0, vehicle={"sag": 0.1}))
    t = sagging.ctrl_t_ns[-10:] / 1e9
    want = mg / (1 - 0.1 * t / 8.0)  # 5 % less thrust at t = 4 s, 10 % at the end
    np.testing.assert_allclose(sagging.ctrl_u[-10:, 2], want, rtol=3e-3)


def test_the_gust_is_rotorpys_sinusoid_with_its_phase_drawn_by_the_seed():
    opts = WindOptions(speed=1.0, direction_deg=90.0, gust=0.4, gust_hz=0.5)
    t = np.arange(0, 4.0, 0.005)
    a, b, c = wind_series(opts, 1, t), wind_series(opts, 1, t), wind_series(opts, 2, t)
    assert a is not None and b is not None and c is not None
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 0.05  # another seed, another phase
    assert np.abs(a[:, 0]).max() < 1e-15 and np.abs(a[:, 2]).max() == 0  # along +y only
    assert a[:, 1].max() == pytest.approx(1.4, abs=1e-3)
    assert a[:, 1].min() == pytest.approx(0.6, abs=1e-3)


def test_the_windy_flight_is_the_same_bits_stepwise_and_close_to_rotorpys_own_step():
    over = {"wind": {"speed": 1.5, "direction_deg": 30.0, "gust": 0.3},
            "vehicle": {"thrust_constant": 0.97, "sag": 0.05}}  # fmt: skip
    fast, slow = fly(_hover(2.0, **over)), fly(_hover(2.0, **over), stepwise=True)
    np.testing.assert_array_equal(fast.x, slow.x)
    still = fly(_hover(2.0))
    assert np.abs(fast.x - still.x).max() > 0.01
    # RotorPy's stock Multirotor.step reads the same wind slot
    wind = {"wind": {"speed": 1.5, "direction_deg": 30.0, "gust": 0.3}}
    ours = fly(_hover(2.0, vehicle={"physics_hz": 100}, **wind))
    stock = fly(
        _hover(
            2.0, vehicle={"physics_hz": 100, "integrator": "solve_ivp", "ivp_rtol": 1e-9}, **wind
        )
    )
    assert np.abs(ours.x - stock.x).max() < 1e-5
    assert np.abs(ours.x - fly(_hover(2.0, vehicle={"physics_hz": 100})).x).max() > 0.01


def test_rotorpys_stock_step_cannot_fly_a_thrust_constant_it_does_not_know():
    with pytest.raises(ConfigError, match="integrator rk4"):
        Vehicle(VehicleOptions(integrator="solve_ivp", sag=0.05))


def test_a_start_beside_the_reference_flies_to_it_and_the_default_dump_is_as_it_was():
    """``start_offset`` puts the vehicle beside the reference's first point at take-off (the
    truth at t = 0 is the reference's first point plus the offset) and the controller flies
    it back; (0, 0) leaves the dump without the key, so every older flight's artifacts stay."""
    assert "start_offset" not in SimOptions().model_dump(mode="json")
    opts = _hover(6.0, start_offset=(0.4, -0.3))
    assert opts.model_dump(mode="json")["start_offset"] == [0.4, -0.3]
    f, home = fly(opts), fly(_hover(6.0))
    np.testing.assert_allclose(f.x[0, :3] - f.ref[0, :3], [0.4, -0.3, 0.0], atol=1e-12)
    np.testing.assert_allclose(home.x[0, :3] - home.ref[0, :3], 0.0, atol=1e-12)
    assert np.linalg.norm(f.x[-1, :2] - f.ref[-1, :2]) < 0.05  # flown back to the reference
    with pytest.raises(ValueError, match="within 10 m"):
        _hover(1.0, start_offset=(11.0, 0.0))
