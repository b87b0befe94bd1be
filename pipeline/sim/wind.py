"""The wind of a flight, by RotorPy's own wind objects (docs/calibration.md#conditions-as-a-stated-family).

RotorPy's ``simulate`` writes ``wind_profile.update(t, x)`` into the state's wind slot
(``s[13:16]``) before each ``Multirotor.step``, and the vehicle's aerodynamics act on the body
airspeed ``R^T (v - wind)``: parasitic drag ``-|v_b| C_D v_b``, rotor drag
``-omega_k K_d v_b,k`` and translational lift (:meth:`qsls.pipeline.sim.vehicle.Vehicle.derivative`
reproduces them). :func:`wind_series` makes that wind for every physics step of a flight,
``w(t) = ConstantWind(speed [cos d, sin d, 0]) + SinusoidWind(gust [cos d, sin d, 0],
gust_hz, phase)``, with the gust's phase (s) drawn uniformly over one period from the
flight's seed (its own stream). RotorPy's Dryden gusts are not offered: its
``dryden_utils`` needs torch, and draws from numpy's global generator (no flight seed).

Without ``vehicle.aero`` the airspeed enters nothing: the wind then has no effect.
"""

from __future__ import annotations

import math

import numpy as np

from qsls.pipeline.sim.options import WindOptions

WIND_STREAM = 3000
"""SeedSequence stream of the gust's phase; the VIO, logs and estimator use their own."""


def wind_vector(options: WindOptions) -> np.ndarray:
    """The unit horizontal direction the wind blows to, ``[cos d, sin d, 0]``."""
    d = math.radians(options.direction_deg)
    return np.array([math.cos(d), math.sin(d), 0.0])


def gust_phase(options: WindOptions, seed: int) -> float:
    """The gust's phase (s), uniform over one period by the flight's seed."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), WIND_STREAM]))
    return float(rng.uniform(0.0, 1.0 / options.gust_hz))


def wind_series(options: WindOptions, seed: int, times: np.ndarray) -> np.ndarray | None:
    """The world wind (m/s, ``(len(times), 3)``) at each of ``times`` (s) from RotorPy's
    ``ConstantWind`` and ``SinusoidWind`` (module doc); None in still air."""
    if options.off:
        return None
    # deferred: RotorPy's wind module is loaded only by a windy flight
    from rotorpy.wind.default_winds import ConstantWind, SinusoidWind

    n = wind_vector(options)
    steady = ConstantWind(*(options.speed * n))
    profiles: list[ConstantWind | SinusoidWind] = [steady]
    if options.gust > 0:
        phase = gust_phase(options, seed)
        profiles.append(
            SinusoidWind(
                amplitudes=options.gust * n,
                frequencies=np.full(3, options.gust_hz),
                phase=np.full(3, phase),
            )
        )
    out = np.zeros((len(times), 3))
    origin = np.zeros(3)
    for i, t in enumerate(np.asarray(times, dtype=float).tolist()):
        for p in profiles:
            out[i] += p.update(t, origin)
    return out
